"""Requests a page may get, over HTTP against a `sil gsu` process with no ECU on its bus: a
malformed one (a body without its length, too long, cut short, not JSON, not an object, a
number not finite or too large, a field of the wrong type or unknown) is answered with a 4xx
and the reason in JSON, never a dropped connection; every endpoint answers at once when the
ECU is silent; and the terminal shows no traceback."""

from __future__ import annotations

import http.client
import json
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ANSWERS = {200, 400, 404, 409, 411, 413, 415, 503, 504}  # (never 500, never no answer)
COMMANDS = ("params", "import", "start", "throttle", "test", "stop", "end-test", "unlock",
            "store", "record/start", "record/stop")  # fmt: skip


@dataclass
class Page:
    port: int
    token: str
    process: subprocess.Popen


@pytest.fixture(scope="module")
def page(sil_process, udp_spec, tmp_path_factory) -> Iterator[Page]:  # noqa: ANN001
    process = sil_process("gsu", "--bus", udp_spec(), "--port", "0",
                          "--out", str(tmp_path_factory.mktemp("gsu")))  # fmt: skip
    url = process.stdout.readline().strip()
    assert "token=" in url, process.stderr.read() if process.poll() is not None else url
    port = int(url.split(":")[-1].split("/")[0])
    yield Page(port, url.split("token=", 1)[1], process)
    if process.poll() is None:
        process.kill()
        process.wait(10)


def _raw(page: Page, head: str, body: bytes = b"") -> tuple[int, dict]:
    """One request as its bytes (``head``: its request line and headers, the host and token
    added); the status and the JSON answer."""
    request = f"{head}\r\nHost: 127.0.0.1:{page.port}\r\nX-GSU-Token: {page.token}\r\n\r\n"
    with socket.create_connection(("127.0.0.1", page.port), timeout=10) as sock:
        sock.sendall(request.encode() + body)
        sock.shutdown(socket.SHUT_WR)
        response = http.client.HTTPResponse(sock)
        response.begin()
        return response.status, json.loads(response.read())


def _post(page: Page, path: str, body: bytes, kind: str = "application/json") -> tuple[int, dict]:
    head = f"POST /api/{path} HTTP/1.1\r\nContent-Type: {kind}\r\nContent-Length: {len(body)}"
    return _raw(page, head, body)


MALFORMED = [
    # (path, headers after the content type, body, status, the reason says)
    ("throttle", "", b'{"pct": 70}', 411, "Content-Length"),
    ("throttle", "Content-Length: seventy", b"{}", 400, "not a byte count"),
    ("throttle", "Content-Length: -4", b"{}", 400, "not a byte count"),
    ("throttle", "Content-Length: 99999999999", b"{}", 413, "a body over"),
    ("throttle", "Content-Length: 40", b'{"pct": 7', 400, "ended before its 40 bytes"),
]
BODIES = [
    # (path, body, status, the reason says)
    ("throttle", b'{"pct": 1e308}', 400, "a number over"),
    ("throttle", b'{"pct": -1e999}', 400, "a number over"),
    ("throttle", b'{"pct": 123456789012345678901234567890}', 400, "a number over"),
    ("throttle", b'{"pct": NaN}', 400, "NaN: not a number JSON has"),
    ("throttle", b'{"pct": Infinity}', 400, "Infinity: not a number JSON has"),
    ("throttle", b'{"pct": "70"}', 400, "pct: a number"),
    ("throttle", b'{"pct": true}', 400, "pct: a number"),
    ("throttle", b'{"pct": 70, "ramp": 2}', 400, "unknown field(s): ramp (it takes: pct)"),
    ("throttle", b"[70]", 400, "the body is a JSON object"),
    ("throttle", b'{"pct": 7', 400, "not JSON"),
    ("throttle", b"\xff\xfe{}", 400, "not JSON"),
    ("throttle", b"[" * 100_000, 400, "not JSON"),
    ("params", b'{"name": 5, "value": 1}', 400, "name: a name"),
    ("params", b'{"name": "egt_limit_k", "value": "hot"}', 400, "value: a number"),
    ("params", b'{"name": "egt_limit_k", "value": []}', 400, "value: a number"),
    ("test", b'{"test": "glow", "seconds": null}', 400, "seconds: a number"),
    ("stop", b'{"now": true}', 400, "unknown field(s): now (it takes: none)"),
    ("nothing", b"{}", 404, "no such command: /api/nothing"),
]


@pytest.mark.parametrize(("path", "headers", "body", "status", "said"), MALFORMED)
def test_a_body_without_its_length_is_refused_with_the_reason(  # noqa: PLR0913
    page: Page, path: str, headers: str, body: bytes, status: int, said: str
) -> None:
    head = f"POST /api/{path} HTTP/1.1\r\nContent-Type: application/json"
    answer = _raw(page, head + (f"\r\n{headers}" if headers else ""), body)
    assert answer[0] == status and said in answer[1]["error"], answer


@pytest.mark.parametrize(("path", "body", "status", "said"), BODIES)
def test_a_malformed_body_is_refused_with_the_reason(
    page: Page, path: str, body: bytes, status: int, said: str
) -> None:
    answer = _post(page, path, body)
    assert answer[0] == status and said in answer[1]["error"], answer


def test_other_malformed_requests_are_refused_with_the_reason(page: Page) -> None:
    assert _post(page, "stop", b"{}", "text/plain") == (415, {"error": "a command is a JSON POST"})
    status, answer = _raw(page, "PUT /api/state HTTP/1.1\r\nContent-Length: 0")
    assert status == 405 and "GET and POST" in answer["error"]
    with socket.create_connection(("127.0.0.1", page.port), timeout=10) as sock:
        sock.sendall(b"NONSENSE\r\n\r\n")
        response = http.client.HTTPResponse(sock)
        response.begin()
        assert response.status == 400 and "error" in json.loads(response.read())


GETS = ("state", "chart", "faults", "recordings", "params", "export", "logbook")
POSTS = [
    ("unlock", {}), ("store", {}), ("stop", {}), ("end-test", {}), ("start", {"confirm": True}),
    ("throttle", {"pct": 70}), ("test", {"test": "glow", "level": 1, "seconds": 1}),
    ("params", {"name": "egt_limit_k", "value": 1250}),
    ("import", {"format": "turbojet-gsu parameters", "parameters": {"egt_limit_k": 1250}}),
]  # fmt: skip


def test_every_endpoint_answers_at_once_when_the_ecu_is_silent(page: Page) -> None:
    for path in GETS:
        started = time.monotonic()
        status, answer = _raw(page, f"GET /api/{path} HTTP/1.1")
        assert time.monotonic() - started < 1.0, path
        if path in ("params", "export", "logbook"):
            assert status == 503 and "the ECU is silent" in answer["error"], (path, answer)
        else:
            assert status == 200, (path, answer)
    for path, body in POSTS:
        started = time.monotonic()
        status, answer = _post(page, path, json.dumps(body).encode())
        assert time.monotonic() - started < 1.0, path
        assert status == 503 and "the ECU is silent" in answer["error"], (path, answer)


JSON = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=False) | st.integers() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                max_size=4),
    max_leaves=12,
)  # fmt: skip
FIELDS = st.sampled_from(["pct", "name", "value", "confirm", "test", "level", "seconds",
                          "parameters", "format"])  # fmt: skip


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    path=st.sampled_from(COMMANDS),
    body=JSON | st.dictionaries(FIELDS, JSON, max_size=3),
    raw=st.none() | st.binary(max_size=24),
)
def test_any_body_is_answered_with_json_and_never_an_error_of_the_page(
    page: Page, path: str, body: object, raw: bytes | None
) -> None:
    data = raw if raw is not None else json.dumps(body).encode()
    status, answer = _post(page, path, data)
    assert status in ANSWERS and (status == 200 or isinstance(answer["error"], str)), answer


def test_the_terminal_shows_no_traceback(page: Page) -> None:
    page.process.terminate()
    _, err = page.process.communicate(timeout=15)
    assert page.process.returncode == 0 and "Traceback" not in err, err
    assert all(line.startswith("sil gsu: recording") for line in err.splitlines()), err
