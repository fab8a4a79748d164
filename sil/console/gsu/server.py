"""The ground-support page's web server: the page, its live stream and its commands.

A standard-library HTTP server (one thread a request) on 127.0.0.1 unless told otherwise. Every
``/api`` request carries the session's token (``X-GSU-Token``, or ``?token=`` where a browser
cannot set a header: the live stream); a request for another host name is refused (a page of
another site cannot reach the server through DNS tricks), and a command is a JSON ``POST``
(which another site's page cannot send without the token). Commands go to the ECU over XCP
(:mod:`sil.console.gsu.xcp_link`); the live values come from the bus
(:mod:`sil.console.gsu.live`) and are pushed at :data:`STREAM_HZ` as server-sent events.
"""

from __future__ import annotations

import hmac
import json
import math
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
from sil.console.gsu.xcp_link import Refused, XcpLink
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
STATIC = ("index.html", "gsu.js", "gsu.css")


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
        try:
            polled = self.link.read_measurements(list(POLLED))
            c = self.link.a2l.characteristics
            for name in POLLED_CHARACTERISTICS:
                if name in c:
                    polled[name] = self.link.read_characteristic(c[name])
            self.polled = polled
        except Refused as exc:
            self.polled = {"error": str(exc)}

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
        rows = []
        for c in self.link.a2l.characteristics.values():
            if c.name.startswith(BENCH_PREFIX):
                continue
            try:
                value = self.link.read_characteristic(c)
                problem = None
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
        if len(values) != c.count or not all(
            isinstance(v, int | float) and math.isfinite(v) for v in values
        ):
            raise Refused(f"{name}: takes {c.count} number(s)")
        self.link.write_characteristic(c, [float(v) for v in values], "parameter")
        return {"name": name, "value": self.link.read_characteristic(c)}

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

        def log_message(self, format: str, *args: object) -> None:  # noqa: A002
            pass  # (no line per request on the terminal)

        # -- plumbing ------------------------------------------------------------------------
        def _send(self, status: int, body: bytes, kind: str, extra: dict | None = None) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            for k, v in (extra or {}).items():
                self.send_header(k, v)
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: int, value: object, extra: dict | None = None) -> None:
            body = strict_json.dumps(value).encode()
            self._send(status, body, "application/json", extra)

        def _refuse(self, status: int, message: str) -> None:
            self._json(status, {"error": message})

        def _allowed(self, query: dict) -> bool:
            if self.headers.get("Host", "") not in hosts:
                self._refuse(HTTPStatus.FORBIDDEN, "unknown host name")
                return False
            token = self.headers.get("X-GSU-Token") or query.get("token", [""])[0]
            if not hmac.compare_digest(token.encode(), gsu.token.encode()):
                self._refuse(HTTPStatus.FORBIDDEN, "open the address `sil gsu` printed")
                return False
            return True

        def _body(self) -> object:
            if self.headers.get("Content-Type", "").split(";")[0] != "application/json":
                raise Refused("a command is a JSON POST")
            length = int(self.headers.get("Content-Length") or 0)
            if length > MAX_BODY:
                raise Refused(f"a body over {MAX_BODY} bytes")
            try:
                return json.loads(self.rfile.read(length) or b"{}")
            except (ValueError, UnicodeDecodeError) as exc:
                raise Refused(f"the body is not JSON: {exc}") from None

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
                return self._answer(gsu.export, disposition)
            route = routes.get(url.path)
            if route is None:
                return self._refuse(HTTPStatus.NOT_FOUND, f"no such page: {url.path}")
            return self._answer(route)

        def _answer(self, route, extra: dict | None = None) -> None:  # noqa: ANN001
            try:
                self._json(HTTPStatus.OK, route(), extra)
            except Refused as exc:
                self._refuse(HTTPStatus.CONFLICT, str(exc))

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
            except (BrokenPipeError, ConnectionResetError):
                pass
            self.close_connection = True

        # -- POST ----------------------------------------------------------------------------
        def do_POST(self) -> None:  # noqa: N802
            url = urlsplit(self.path)
            if not self._allowed(parse_qs(url.query)):
                return
            try:
                body = self._body()
                answer = self._command(url.path, body if isinstance(body, dict) else {})
            except Refused as exc:
                return self._refuse(HTTPStatus.CONFLICT, str(exc))
            except KeyError as exc:
                return self._refuse(HTTPStatus.NOT_FOUND, str(exc.args[0]))
            self._json(HTTPStatus.OK, answer)

        def _command(self, path: str, body: dict) -> object:
            link = gsu.link
            if path == "/api/params":
                return gsu.write_parameter(str(body.get("name")), body.get("value"))
            if path == "/api/import":
                return gsu.import_file(body)
            if path == "/api/start":
                if body.get("confirm") is not True:
                    raise Refused("start: not confirmed")
                link.bench("bench_arm", 1)
                return {"started": True}
            if path == "/api/throttle":
                pct = body.get("pct")
                if not isinstance(pct, int | float) or not math.isfinite(pct):
                    raise Refused("throttle: a number, %N")
                link.bench("bench_throttle", float(pct))
                return {"throttle": pct}
            if path == "/api/test":
                level, seconds = _number(body, "level"), _number(body, "seconds")
                link.run_test(str(body.get("test")), level, seconds)
                return {"test": body.get("test")}
            simple = {
                "/api/stop": lambda: link.bench("bench_stop", 1),
                "/api/end-test": lambda: link.bench_raw("bench_test", 0),
                "/api/unlock": link.unlock,
                "/api/store": link.store,
                "/api/record/start": gsu.record_start,
                "/api/record/stop": gsu.record_stop,
            }
            if path not in simple:
                raise KeyError(f"no such command: {path}")
            return simple[path]() or {"done": path.rsplit("/", 1)[1]}

    return Handler


def _number(body: dict, key: str) -> float:
    value = body.get(key, 0)
    if not isinstance(value, int | float) or not math.isfinite(value):
        raise Refused(f"{key}: a number")
    return float(value)


def serve(gsu: Gsu, host: str, port: int) -> ThreadingHTTPServer:
    """The server, bound (``port`` 0: any free port); ``serve_forever`` runs it."""
    server = ThreadingHTTPServer((host, port), None)  # type: ignore[arg-type]
    bound = server.server_address[1]
    names = {host, "127.0.0.1", "localhost", "[::1]"}
    hosts = {f"{n}:{bound}" for n in names}
    server.RequestHandlerClass = _handler(gsu, hosts)
    server.daemon_threads = True
    return server
