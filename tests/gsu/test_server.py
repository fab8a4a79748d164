"""The page's server on its own (no ECU on the bus): local only, every /api request needs the
session's token and a known host name, a command is a JSON POST, a start needs its
confirmation, and what the ECU cannot be asked (it is silent) comes back at once as a refusal
saying so, not a crash or a wait."""

from __future__ import annotations

import json
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from sil.console.gsu.app import App
from sil.record.a2l import A2l

TOKEN = "test-token-123"


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Iterator[str]:
    from protocol.bus import unique_udp_spec

    app = App.open(str(unique_udp_spec()), A2l({}, None), (0x700, 0x701),
                   tmp_path_factory.mktemp("gsu"), TOKEN)  # fmt: skip
    server = app.serve("127.0.0.1", 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()
    app.close()


def _call(url: str, body: object = None, headers: dict | None = None) -> tuple[int, dict | str]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            text = response.read().decode()
            status = response.status
    except urllib.error.HTTPError as exc:
        text, status = exc.read().decode(), exc.code
    try:
        return status, json.loads(text)
    except ValueError:
        return status, text


def _auth(**more: str) -> dict:
    return {"X-GSU-Token": TOKEN, **more}


def test_the_page_and_its_files_are_served(page: str) -> None:
    status, text = _call(page + "/")
    assert status == 200 and 'data-testid="speed"' in text
    for name in ("gsu.js", "gsu.css"):
        assert _call(f"{page}/{name}")[0] == 200
    assert _call(page + "/../pyproject.toml")[0] == 404


def test_every_api_request_needs_the_token_and_a_local_host_name(page: str) -> None:
    assert _call(page + "/api/state")[0] == 403
    assert _call(page + "/api/state", headers={"X-GSU-Token": "wrong"})[0] == 403
    status, answer = _call(page + "/api/state", headers=_auth(Host="evil.example:80"))
    assert status == 403 and answer == {"error": "unknown host name"}
    status, state = _call(page + "/api/state", headers=_auth())
    assert status == 200 and state["xcp"]["ids"] == ["0x700", "0x701"]
    assert _call(f"{page}/api/state?token={TOKEN}")[0] == 200  # (the event stream's way)


def test_commands_are_json_posts_and_a_start_needs_its_confirmation(page: str) -> None:
    status, answer = _call(page + "/api/start", {"confirm": True}, _auth())
    assert status == 415 and answer["error"] == "a command is a JSON POST"
    json_post = _auth(**{"Content-Type": "application/json"})
    status, answer = _call(page + "/api/start", {}, json_post)
    assert status == 409 and answer["error"] == "start: not confirmed"
    status, answer = _call(page + "/api/throttle", {"pct": "fast"}, json_post)
    assert status == 400 and "a number" in answer["error"]
    status, answer = _call(page + "/api/nothing", {}, json_post)
    assert status == 404
    status, answer = _call(page + "/api/record/stop", {}, json_post)
    assert status == 409 and answer["error"] == "no recording under way"


def test_a_silent_ecu_is_a_refusal_at_once(page: str) -> None:
    json_post = _auth(**{"Content-Type": "application/json"})
    status, answer = _call(page + "/api/stop", {}, json_post)
    assert status == 409 and "not in the A2L" in answer["error"]
    started = time.monotonic()
    status, answer = _call(page + "/api/unlock", {}, json_post)
    assert (
        status == 503
        and answer["error"] == "unlock: the ECU is silent (no status frame on the bus)"
    )
    assert time.monotonic() - started < 1.0
    status, answer = _call(page + "/api/logbook", headers=_auth())
    assert status == 409 and "no logbook" in answer["error"]


def test_sil_gsu_listens_on_the_loopback_unless_told() -> None:
    import argparse

    from sil.commands import gsu

    parser = argparse.ArgumentParser()
    gsu.add_arguments(parser)
    assert parser.parse_args(["--bus", "udp:239.255.7.7"]).listen == "127.0.0.1"
    assert parser.parse_args(["--bus", "vcan", "--listen", "0.0.0.0"]).listen == "0.0.0.0"


def test_sil_gsu_refuses_bad_input_with_exit_2(sil, tmp_path, udp_spec) -> None:  # noqa: ANN001
    cases = [
        (["--a2l", str(tmp_path / "none.a2l")], "none.a2l: no such file"),
        (["--out", str(tmp_path / "nowhere")], "nowhere: not a folder"),
        (["--out", "/proc/self"], "--out /proc/self: on the kernel's proc file system"),
        (["--out", "/dev"], "--out /dev: on the kernel's devtmpfs file system"),
        (["--port", "70000"], "--port"),
    ]
    for args, said in cases:
        done = sil("gsu", "--bus", udp_spec(), *args, timeout=60)
        assert done.returncode == 2 and said in done.stderr, (args, done.stderr)
    done = sil("gsu", "--bus", "nosuchinterface:x", timeout=60)
    assert done.returncode == 2 and "nosuchinterface" in done.stderr
    (tmp_path / "bad.a2l").write_text('ASAP2_VERSION 1 71\n/begin PROJECT p ""\n')
    done = sil("gsu", "--bus", udp_spec(), "--a2l", str(tmp_path / "bad.a2l"), timeout=60)
    assert done.returncode == 2 and "bad.a2l" in done.stderr, done.stderr


def test_sil_gsu_says_when_its_port_is_taken(sil, udp_spec) -> None:  # noqa: ANN001
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = sil("gsu", "--bus", udp_spec(), "--port", str(port), timeout=60)
    assert done.returncode == 2 and f"cannot listen on 127.0.0.1:{port}" in done.stderr


def test_a_recording_that_cannot_be_written_is_kept(tmp_path) -> None:  # noqa: ANN001
    import can

    from sil.console.gsu.live import Live
    from sil.console.gsu.server import Gsu
    from sil.console.gsu.xcp_link import Refused

    gsu = Gsu(Live(), None, tmp_path / "gone", TOKEN)  # type: ignore[arg-type]
    frames = [can.Message(arbitration_id=0x100 + k, data=bytes(8), is_extended_id=False)
              for k in range(5)]  # fmt: skip
    gsu.record_start()
    for k, frame in enumerate(frames[:3]):
        gsu.live.feed(frame, 1e9 + k)
    with pytest.raises(Refused, match="gone/gsu-.*cannot write.*the recording goes on"):
        gsu.record_stop()
    for k, frame in enumerate(frames[3:], 3):
        gsu.live.feed(frame, 1e9 + k)
    gsu.out_dir = tmp_path
    done = gsu.record_stop()
    assert done["frames"] == 5 and Path(done["path"]).parent == tmp_path


def test_the_parameters_list_gives_up_in_its_budget_and_says_why(tmp_path, monkeypatch) -> None:  # noqa: ANN001
    from types import SimpleNamespace

    from sil.console.gsu import server
    from sil.console.gsu.live import Live
    from sil.console.gsu.xcp_link import ANOTHER_MASTER, Unavailable

    read: list[str] = []
    heard = [True]

    class SlowLink:  # every read answered, each after another master's command came near it
        a2l = SimpleNamespace(characteristics={
            name: SimpleNamespace(name=name, kind="VALUE", unit="K", lower=0, upper=2, comment="")
            for name in ("bench_arm", "a", "b", "c", "d")
        })  # fmt: skip
        problem = None

        def read_characteristic(self, c) -> float:  # noqa: ANN001
            time.sleep(0.05)
            read.append(c.name)
            return 1.0

        def status(self) -> dict:
            return {"another_master": heard[0]}

    monkeypatch.setattr(server, "PARAMS_BUDGET_S", 0.12)
    gsu = server.Gsu(Live(), SlowLink(), tmp_path, TOKEN)  # type: ignore[arg-type]
    with pytest.raises(Unavailable, match=rf"parameters: 3 of 4 read in 0.12 s; {ANOTHER_MASTER}"):
        gsu.parameters()
    assert read == ["a", "b", "c"]  # the bench's commands are not parameters
    heard[0] = False
    with pytest.raises(Unavailable, match="the ECU answers slowly"):
        gsu.parameters()
