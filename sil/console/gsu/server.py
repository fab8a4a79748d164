"""The ground-support page's web server: the page, its live stream and its commands.

A standard-library HTTP server (one thread a request) on 127.0.0.1 unless told otherwise. Every
``/api`` request carries the session's token (``X-GSU-Token``, or ``?token=`` where a browser
cannot set a header: the live stream); a request for another host name is refused (a page of
another site cannot reach the server through DNS tricks), and a command is a JSON ``POST``
(which another site's page cannot send without the token). Commands go to the ECU over XCP
(:mod:`sil.console.gsu.xcp_link`); the live values come from the bus
(:mod:`sil.console.gsu.live`) and are pushed at :data:`STREAM_HZ` as server-sent events.

Every answer is JSON; a refusal is ``{"error": reason}`` with its status: 400 for a malformed
request (a body that is not a JSON object, a number that is not finite or too large, a field of
the wrong type or unknown), 411/413/415 for a body without its length, too long, or not JSON,
404 for no such page or command, 409 for what the ECU refuses, 503 when the ECU cannot be asked
now (silent, only just back, another XCP master on the bus) and 504 when it did not answer.
"""

from __future__ import annotations

import hmac
import json
import math
import sys
import threading
import time
from datetime import UTC, datetime
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from protocol import strict_json
from sil.console.gsu.live import Live
from sil.console.gsu.xcp_link import ANOTHER_MASTER, Refused, Unavailable, XcpLink
from sil.record import mdf

STREAM_HZ = 20.0
POLL_S = 0.5  # the values read over XCP for the dashboard, this often
# what the dashboard reads over XCP: measurements, and characteristics (the limits, the bench's)
POLLED = ("egt_start_target", "demand_source", "test_active", "test_time_left")
POLLED_CHARACTERISTICS = ("bench_throttle", "egt_limit_k", "start_egt_limit_k")
LOGBOOK_PREFIX = "log_"
BENCH_PREFIX = "bench_"  # the A2L's bench commands: not parameters of the engine
PARAM_FILE = "turbojet-gsu parameters"
MAX_BODY = 1 << 20
MAX_NUMBER = 1e15  # a number in a request, at most this large
SOCKET_TIMEOUT_S = 10.0  # a request (its headers, its body) comes within this
PARAMS_BUDGET_S = 10.0  # the parameters' listing gives up after this (about 1 s alone on the bus)
# a command's fields (None: any, the parameter file's own)
FIELDS: dict[str, frozenset[str] | None] = {
    "/api/params": frozenset({"name", "value"}),
    "/api/import": None,
    "/api/start": frozenset({"confirm"}),
    "/api/throttle": frozenset({"pct"}),
    "/api/test": frozenset({"test", "level", "seconds"}),
    **{f"/api/{name}": frozenset() for name in
       ("stop", "end-test", "unlock", "store", "record/start", "record/stop")},
}  # fmt: skip
STATIC = ("index.html", "gsu.js", "gsu.css")


class BadRequest(Exception):
    """A request the page cannot take as it is: its HTTP status and the reason."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def is_number(value: object) -> bool:
    """A JSON number (a boolean is not one)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


class Gsu:
    """What the server serves: the live values, the XCP session, recordings."""

    def __init__(self, live: Live, link: XcpLink, out_dir: Path, token: str) -> None:
        self.live = live
        self.link = link
        self.out_dir = out_dir
        self.token = token
        self.polled: dict = {}
        self.recordings: list[dict] = []
        self._stop = threading.Event()

    # -- the slow values, over XCP -------------------------------------------------------------
    def poll_forever(self) -> None:
        while not self._stop.wait(POLL_S):
            self.poll()

    def poll(self) -> None:
        """The dashboard's XCP values, or what kept them from being read (whatever it was: the
        poller goes on, and shows them again once the ECU answers)."""
        try:
            polled = self.link.read_measurements(list(POLLED))
            c = self.link.a2l.characteristics
            for name in POLLED_CHARACTERISTICS:
                if name in c:
                    polled[name] = self.link.read_characteristic(c[name])
            self.polled = polled
        except Refused as exc:
            self.polled = {"error": str(exc)}
        except Exception as exc:  # noqa: BLE001 (the poller must not end)
            self.polled = {"error": f"read: {type(exc).__name__}: {exc}"}

    def stop(self) -> None:
        self._stop.set()

    def state(self) -> dict:
        out = self.live.snapshot()
        out.update({f"x_{k}": v for k, v in self.polled.items()})
        out["xcp"] = self.link.status()
        out["sent_s"] = time.time()
        return out

    # -- parameters ----------------------------------------------------------------------------
    def parameters(self) -> list[dict]:
        """Every parameter of the A2L as the ECU holds it, or :class:`Unavailable` when they
        cannot all be read within :data:`PARAMS_BUDGET_S` (another master's commands keep coming
        near the page's)."""
        rows: list[dict] = []
        every = self.link.a2l.characteristics
        names = [name for name in every if not name.startswith(BENCH_PREFIX)]
        deadline = time.monotonic() + PARAMS_BUDGET_S
        for c in (every[name] for name in names):
            if time.monotonic() > deadline:
                heard = self.link.status()["another_master"]
                why = ANOTHER_MASTER if heard else self.link.problem or "the ECU answers slowly"
                raise Unavailable(f"parameters: {len(rows)} of {len(names)} read in "
                                  f"{PARAMS_BUDGET_S:g} s; {why}")  # fmt: skip
            try:
                value = self.link.read_characteristic(c)
                problem = None
            except Unavailable:
                raise
            except Refused as exc:
                value, problem = None, str(exc)
            rows.append(
                {
                    "name": c.name,
                    "kind": c.kind,
                    "value": value,
                    "unit": c.unit,
                    "lower": c.lower,
                    "upper": c.upper,
                    "comment": c.comment,
                    "error": problem,
                }
            )
        return rows

    def write_parameter(self, name: str, value: object) -> dict:
        c = self.link.a2l.characteristics.get(name)
        if c is None or name.startswith(BENCH_PREFIX):
            raise Refused(f"{name}: no such parameter in the A2L")
        values = value if isinstance(value, list) else [value]
        if len(values) != c.count or not all(is_number(v) for v in values):
            raise Refused(f"{name}: takes {c.count} number(s)")
        asked = [float(v) for v in values]
        self.link.write_characteristic(c, asked, "parameter")
        held = self.link.read_characteristic(c)
        meant = [c.to_value(c.to_raw(v)) for v in asked]
        if not all(
            math.isclose(h, m, rel_tol=1e-9, abs_tol=1e-12)
            for h, m in zip(held if isinstance(held, list) else [held], meant, strict=True)
        ):
            raise Refused(f"{name}: written, but the ECU holds {held} (another master wrote it?)")
        return {"name": name, "value": held}

    def export(self) -> dict:
        params = {
            row["name"]: {"value": row["value"], "unit": row["unit"]}
            for row in self.parameters()
            if row["error"] is None
        }
        return {
            "format": PARAM_FILE,
            "version": 1,
            "ecu": self.link.identification,
            "a2l": self.link.a2l.name,
            "epk": self.link.a2l.epk,
            "saved": datetime.now(UTC).isoformat(timespec="seconds"),
            "parameters": params,
        }

    def import_file(self, document: object) -> dict:
        """Write every parameter of an exported file that differs from the ECU's; each refusal
        with the ECU's reason, the others written."""
        if not isinstance(document, dict) or document.get("format") != PARAM_FILE:
            raise Refused(f"not a parameter file of this page (its 'format' is not {PARAM_FILE!r})")
        params = document.get("parameters")
        if not isinstance(params, dict):
            raise Refused("the file has no 'parameters' map")
        current = {row["name"]: row["value"] for row in self.parameters()}
        written, refused, unknown = [], [], []
        for name, entry in params.items():
            if name not in current:
                unknown.append(name)
                continue
            value = entry.get("value") if isinstance(entry, dict) else entry
            if value == current[name]:
                continue
            try:
                self.write_parameter(name, value)
                written.append(name)
            except Unavailable as exc:
                before = ", ".join(written) or "none"
                raise Unavailable(f"{exc} (written before: {before})", exc.timed_out) from None
            except Refused as exc:
                refused.append({"name": name, "reason": str(exc)})
        return {"written": written, "refused": refused, "unknown": unknown}

    def logbook(self) -> dict:
        names = [n for n in self.link.a2l.measurements if n.startswith(LOGBOOK_PREFIX)]
        if not names:
            raise Refused("this ECU's A2L has no logbook")
        return self.link.read_measurements(names)

    # -- recording -----------------------------------------------------------------------------
    def record_start(self) -> dict:
        if not self.live.start_recording():
            raise Refused("a recording is already under way")
        return {"recording": True}

    def record_stop(self) -> dict:
        frames = self.live.stop_recording()
        if frames is None:
            raise Refused("no recording under way")
        if not frames:
            raise Refused("the recording holds no frame (is the engine's bus quiet?)")
        stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        path = self.out_dir / f"gsu-{stamp}.mf4"
        table = mdf.FrameTable.of(frames)
        base = mdf.time_base(float(table.t[0]), None, lambda: (time.time(), "the page"))
        try:
            mdf.write_bus_log(path, table, base, note="recorded from the ground-support page")
        except (OSError, mdf.MdfUnavailable) as exc:  # (WriteError names the file)
            self.live.start_recording(frames)  # nothing lost: the recording goes on
            raise Refused(f"{exc}; the recording goes on, stop it again to write it") from None
        done = {"path": str(path), "frames": len(frames), "bytes": path.stat().st_size}
        self.recordings.append(done)
        return done


def _handler(gsu: Gsu, hosts: set[str]) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "turbojet-gsu"
        protocol_version = "HTTP/1.1"
        timeout = SOCKET_TIMEOUT_S

        def log_message(self, format: str, *args: object) -> None:  # noqa: A002
            pass  # (no line per request on the terminal)

        # -- plumbing ------------------------------------------------------------------------
        def _send(self, status: int, body: bytes, kind: str, extra: dict | None = None) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            if self.close_connection:
                self.send_header("Connection", "close")
            for k, v in (extra or {}).items():
                self.send_header(k, v)
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)

        def _json(self, status: int, value: object, extra: dict | None = None) -> None:
            body = strict_json.dumps(value).encode()
            self._send(status, body, "application/json", extra)

        def _refuse(self, status: int, message: str) -> None:
            self._json(status, {"error": message})

        def send_error(self, code: int, message: str | None = None, explain: str | None = None):
            """http.server's own refusals (a malformed request line or header), as JSON."""
            self.close_connection = True
            self.request_version = "HTTP/1.1"  # (an answer with its status line, whatever came)
            self._refuse(code, message or HTTPStatus(code).phrase)

        def _allowed(self, query: dict) -> bool:
            if self.headers.get("Host", "") not in hosts:
                self._refuse(HTTPStatus.FORBIDDEN, "unknown host name")
                return False
            token = self.headers.get("X-GSU-Token") or query.get("token", [""])[0]
            if not hmac.compare_digest(token.encode(), gsu.token.encode()):
                self._refuse(HTTPStatus.FORBIDDEN, "open the address `sil gsu` printed")
                return False
            return True

        def _body(self) -> dict:
            """The request's JSON object (an empty body: no fields)."""
            if self.headers.get("Content-Type", "").split(";")[0].strip() != "application/json":
                raise BadRequest(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "a command is a JSON POST")
            length = _length(self.headers.get("Content-Length"))
            if length > MAX_BODY:
                self.close_connection = True  # (the body is not read)
                raise BadRequest(
                    HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"a body over {MAX_BODY} bytes"
                )
            try:
                raw = self.rfile.read(length)
            except OSError:
                raw = b""
            if len(raw) < length:
                self.close_connection = True
                raise BadRequest(
                    HTTPStatus.BAD_REQUEST, f"the body ended before its {length} bytes"
                )
            return _json_object(raw)

        def _run(self, route, extra: dict | None = None) -> None:  # noqa: ANN001
            """``route()``'s answer as JSON, or its refusal with its status."""
            try:
                answer = route()
            except BadRequest as exc:
                return self._refuse(exc.status, str(exc))
            except Unavailable as exc:
                status = (
                    HTTPStatus.GATEWAY_TIMEOUT if exc.timed_out else HTTPStatus.SERVICE_UNAVAILABLE
                )
                return self._refuse(status, str(exc))
            except Refused as exc:
                return self._refuse(HTTPStatus.CONFLICT, str(exc))
            except Exception as exc:  # noqa: BLE001 (an answer, never a dropped connection)
                print(f"sil gsu: {self.command} {self.path}: {type(exc).__name__}: {exc}",
                      file=sys.stderr)  # fmt: skip
                return self._refuse(
                    HTTPStatus.INTERNAL_SERVER_ERROR, f"{type(exc).__name__}: {exc}"
                )
            return self._json(HTTPStatus.OK, answer, extra)

        # -- GET -----------------------------------------------------------------------------
        def do_GET(self) -> None:  # noqa: N802
            url = urlsplit(self.path)
            query = parse_qs(url.query)
            if not url.path.startswith("/api/"):
                return self._static(url.path)
            if not self._allowed(query):
                return None
            routes = {
                "/api/state": gsu.state,
                "/api/chart": gsu.live.chart,
                "/api/faults": gsu.live.faults_seen,
                "/api/params": gsu.parameters,
                "/api/logbook": gsu.logbook,
                "/api/recordings": lambda: gsu.recordings,
            }
            if url.path == "/api/stream":
                return self._stream()
            if url.path == "/api/export":
                name = f"parameters-{datetime.now(UTC).strftime('%Y%m%d-%H%M%S')}.json"
                disposition = {"Content-Disposition": f'attachment; filename="{name}"'}
                return self._run(gsu.export, disposition)
            route = routes.get(url.path)
            if route is None:
                return self._refuse(HTTPStatus.NOT_FOUND, f"no such page: {url.path}")
            return self._run(route)

        def _static(self, path: str) -> None:
            name = "index.html" if path in ("/", "/index.html") else path.lstrip("/")
            if self.headers.get("Host", "") not in hosts:
                return self._refuse(HTTPStatus.FORBIDDEN, "unknown host name")
            if name not in STATIC:
                return self._refuse(HTTPStatus.NOT_FOUND, f"no such page: {path}")
            kinds = {"html": "text/html", "js": "text/javascript", "css": "text/css"}
            body = resources.files("sil.console.gsu").joinpath("page", name).read_bytes()
            kind = kinds[name.rsplit(".", 1)[1]]
            return self._send(HTTPStatus.OK, body, f"{kind}; charset=utf-8")

        def _stream(self) -> None:
            """Server-sent events: the state, :data:`STREAM_HZ` times a second."""
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            period = 1.0 / STREAM_HZ
            next_s = time.monotonic()
            try:
                while not gsu._stop.is_set():
                    data = strict_json.dumps(gsu.state())
                    self.wfile.write(f"data: {data}\n\n".encode())
                    self.wfile.flush()
                    next_s += period
                    time.sleep(max(0.0, next_s - time.monotonic()))
            except OSError:  # the page went away
                pass
            self.close_connection = True

        # -- POST ----------------------------------------------------------------------------
        def do_POST(self) -> None:  # noqa: N802
            self.close_connection = True  # (a refused command's body may be left unread)
            url = urlsplit(self.path)
            if not self._allowed(parse_qs(url.query)):
                return None
            if url.path not in FIELDS:
                return self._refuse(HTTPStatus.NOT_FOUND, f"no such command: {url.path}")
            return self._run(lambda: self._command(url.path, self._fields(url.path)))

        def _fields(self, path: str) -> dict:
            body = self._body()
            allowed = FIELDS[path]
            unknown = sorted(set(body) - allowed) if allowed is not None else []
            if unknown:
                takes = ", ".join(sorted(allowed or ())) or "none"
                said = f"{path}: unknown field(s): {', '.join(unknown)} (it takes: {takes})"
                raise BadRequest(HTTPStatus.BAD_REQUEST, said)
            return body

        def _command(self, path: str, body: dict) -> object:
            link = gsu.link
            if path == "/api/params":
                name, value = _text(body, "name"), body.get("value")
                values = value if isinstance(value, list) else [value]
                if not values or not all(is_number(v) for v in values):
                    raise BadRequest(HTTPStatus.BAD_REQUEST, "value: a number, or a list of them")
                return gsu.write_parameter(name, value)
            if path == "/api/import":
                return gsu.import_file(body)
            if path == "/api/start":
                if body.get("confirm") is not True:
                    raise Refused("start: not confirmed")
                link.bench("bench_arm", 1)
                return {"started": True}
            if path == "/api/throttle":
                pct = _number(body, "pct", None)
                link.bench("bench_throttle", pct)
                return {"throttle": pct}
            if path == "/api/test":
                level, seconds = _number(body, "level", 0.0), _number(body, "seconds", 0.0)
                test = _text(body, "test")
                link.run_test(test, level, seconds)
                return {"test": test}
            simple = {
                "/api/stop": lambda: link.bench("bench_stop", 1),
                "/api/end-test": lambda: link.bench_raw("bench_test", 0),
                "/api/unlock": link.unlock,
                "/api/store": link.store,
                "/api/record/start": gsu.record_start,
                "/api/record/stop": gsu.record_stop,
            }
            return simple[path]() or {"done": path.rsplit("/", 1)[1]}

        def _not_allowed(self) -> None:
            self.close_connection = True
            self._refuse(
                HTTPStatus.METHOD_NOT_ALLOWED, f"{self.command}: the page takes GET and POST"
            )

        do_PUT = do_DELETE = do_PATCH = do_HEAD = do_OPTIONS = _not_allowed  # noqa: N815

    return Handler


def _length(text: str | None) -> int:
    """A body's Content-Length."""
    if text is None:
        raise BadRequest(HTTPStatus.LENGTH_REQUIRED, "a command's body needs its Content-Length")
    if not text.strip().isdigit():
        raise BadRequest(HTTPStatus.BAD_REQUEST, f"Content-Length {text[:40]!r}: not a byte count")
    return int(text)


def _json_number(text: str) -> float | int:
    value = float(text)
    if not abs(value) <= MAX_NUMBER:
        raise ValueError(f"{text[:40]}: a number over {MAX_NUMBER:g}")
    return int(text) if text.lstrip("-").isdigit() else value


def _no_constant(name: str) -> None:
    raise ValueError(f"{name}: not a number JSON has")


def _json_object(raw: bytes) -> dict:
    """A body as a JSON object; numbers finite and at most :data:`MAX_NUMBER` large."""
    try:
        body = json.loads(raw or b"{}", parse_float=_json_number, parse_int=_json_number,
                          parse_constant=_no_constant)  # fmt: skip
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise BadRequest(
            HTTPStatus.BAD_REQUEST, f"the body is not JSON the page takes: {exc}"
        ) from None
    if not isinstance(body, dict):
        raise BadRequest(HTTPStatus.BAD_REQUEST, "the body is a JSON object")
    return body


def _number(body: dict, key: str, default: float | None) -> float:
    value = body.get(key, default)
    if not is_number(value):
        raise BadRequest(HTTPStatus.BAD_REQUEST, f"{key}: a number")
    return float(value)  # type: ignore[arg-type]


def _text(body: dict, key: str) -> str:
    value = body.get(key)
    if not isinstance(value, str):
        raise BadRequest(HTTPStatus.BAD_REQUEST, f"{key}: a name (text)")
    return value


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def handle_error(self, request: object, client_address: object) -> None:
        """A connection that failed under a request: one line, no traceback."""
        exc = sys.exc_info()[1]
        if not isinstance(exc, OSError):
            print(f"sil gsu: a request failed: {type(exc).__name__}: {exc}", file=sys.stderr)


def serve(gsu: Gsu, host: str, port: int) -> ThreadingHTTPServer:
    """The server, bound (``port`` 0: any free port); ``serve_forever`` runs it."""
    server = _Server((host, port), None)  # type: ignore[arg-type]
    bound = server.server_address[1]
    names = {host, "127.0.0.1", "localhost", "[::1]"}
    hosts = {f"{n}:{bound}" for n in names}
    server.RequestHandlerClass = _handler(gsu, hosts)
    return server
