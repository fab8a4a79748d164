"""The page beside another XCP master (a pyXCP master reading as fast as it can, or a second
page), and beside an ECU that pauses or restarts, over its HTTP API with a plant, an ECU and
`sil gsu` each a process on a loopback bus: every value a page shows is this ECU's (the
firmware's default parameters, which a fresh flash holds), or the page says why it shows none;
a write is reported done only when the ECU holds it (the other page reads it); and the page
shows live values again by itself once the ECU runs again, without a restart."""

from __future__ import annotations

import contextlib
import json
import logging
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.error
from collections.abc import Iterator
from pathlib import Path

import pytest

from ecu.params import EcuParams
from ecu.service.param_table import TABLE
from protocol.bus import open_bus
from sil.bench import gsu
from sil.record.xcp_master import connect, master

pytestmark = pytest.mark.slow

ANOTHER = "another XCP master is on the bus"
SPECS = {spec.name: spec for spec in TABLE if spec.element is None}


def _known(name: str) -> float:
    """A parameter's value in a fresh ECU: the firmware's default, as its Q format holds it."""
    spec = SPECS[name]
    return spec.to_value(spec.to_raw(getattr(EcuParams(), spec.field)))


def _call(station: gsu.Station, path: str, body: dict | None = None) -> tuple[int, object]:
    try:
        return 200, station.api(path, body)
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def _live(station: gsu.Station, timeout_s: float) -> dict:
    """The page's state once it shows the ECU's status frames and its XCP values again."""
    deadline = time.monotonic() + timeout_s
    while True:
        state = _call(station, "/api/state")[1]
        if not state["ecu_silent"] and "x_egt_limit_k" in state:  # type: ignore[index]
            return state  # type: ignore[return-value]
        assert time.monotonic() < deadline, f"the page not live again: {state}"
        time.sleep(0.1)


def _answered(station: gsu.Station, path: str, timeout_s: float = 10.0) -> object:
    """``path``'s answer once the page can ask the ECU (503 and 504 say it cannot yet)."""
    deadline = time.monotonic() + timeout_s
    while (answer := _call(station, path))[0] != 200:
        assert answer[0] in (503, 504) and time.monotonic() < deadline, answer
        time.sleep(0.2)
    return answer[1]


@contextlib.contextmanager
def another_master(spec: str, address: int) -> Iterator[list[int]]:
    """A master of its own on the bus: it connects (which locks the ECU again) and reads
    ``address`` as fast as it can, over again whatever it meets; yields its count of reads."""
    stop, reads = threading.Event(), [0]
    logging.getLogger("pyxcp").disabled = True

    def run() -> None:
        bus = open_bus(spec)
        try:
            while not stop.is_set():
                with contextlib.suppress(Exception), master(bus, (0x700, 0x701), None) as x:
                    x.transport.timeout = 300_000_000  # ns
                    connect(x, 2.0)
                    for _ in range(20):
                        x.shortUpload(4, address)
                        reads[0] += 1
        finally:
            bus.shutdown()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield reads
    finally:
        stop.set()
        thread.join(10)


def _address(station: gsu.Station, name: str) -> int:
    from sil.commands import a2l as a2l_command
    from sil.record.a2l import read_a2l

    path = station.folder / "ecu.a2l"
    path.write_text(a2l_command.text_for("python", None, None), "latin-1")
    return read_a2l(path).characteristics[name].address


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # (pyXCP's)
def test_beside_another_master_the_page_shows_only_its_own_answers(bench: gsu.Station) -> None:
    limit = _known("egt_limit_k")
    _live(bench, 30)
    shown, refused = [], []
    with another_master(bench.spec, _address(bench, "start_egt_limit_k")) as reads:
        deadline = time.monotonic() + 4.0
        while time.monotonic() < deadline:
            state = _call(bench, "/api/state")[1]
            if "x_egt_limit_k" in state:  # type: ignore[operator]
                shown.append(state["x_egt_limit_k"])  # type: ignore[index]
            else:
                refused.append(state["x_error"])  # type: ignore[index]
            time.sleep(0.05)
        status, params = _call(bench, "/api/params")
        assert reads[0] > 20  # (the other master was at work)
    assert shown and all(value == limit for value in shown), shown
    assert all(ANOTHER in said or "just back" in said for said in refused), refused
    if status == 200:
        values = {row["name"]: row["value"] for row in params}  # type: ignore[union-attr]
        assert all(values[name] == _known(name) for name in SPECS if name in values)
    else:
        assert status == 503 and ANOTHER in params["error"], params  # type: ignore[index]
    state = _live(bench, 10)  # the other master gone: the page alone again
    assert state["x_egt_limit_k"] == limit and "x_error" not in state


@contextlib.contextmanager
def second_page(station: gsu.Station) -> Iterator[gsu.Station]:
    """Another `sil gsu` on the station's bus: a second XCP master polling the same ECU."""
    log_path = station.folder / "gsu-second.log"
    with log_path.open("w") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "sil.cli", "gsu", "--bus", station.spec, "--port", "0"],
            stdout=log, stderr=subprocess.STDOUT, cwd=station.folder,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while not (found := re.search(r"http://\S+", log_path.read_text())):
            assert process.poll() is None and time.monotonic() < deadline, log_path.read_text()
            time.sleep(0.1)
        yield gsu.Station(station.spec, found.group(0), station.folder, {"gsu": process})
    finally:
        process.terminate()
        process.wait(15)
    assert "Traceback" not in log_path.read_text()


def test_two_pages_show_their_own_answers_and_a_write_done_is_in_the_ecu(
    bench: gsu.Station,
) -> None:
    limit = _known("egt_limit_k")
    _live(bench, 30)
    with second_page(bench) as other:
        _live(other, 30)
        for _ in range(20):  # both polling meanwhile
            for page in (bench, other):
                state = _call(page, "/api/state")[1]
                assert state.get("x_egt_limit_k", limit) == limit, state  # type: ignore[union-attr]
            time.sleep(0.1)
        for k in range(30):  # (the other page's start locked the ECU again: unlock first)
            status, answer = _call(bench, "/api/unlock", {})
            if status == 200:
                value = 1200.0 + k
                status, answer = _call(bench, "/api/params", {"name": "egt_limit_k",
                                                              "value": value})  # fmt: skip
            if status == 200:
                assert answer == {"name": "egt_limit_k", "value": value}
                break
            assert status in (409, 503), answer  # locked again, or the other page spoke
        assert status == 200, answer
        deadline = time.monotonic() + 10
        while (held := _call(other, "/api/state")[1].get("x_egt_limit_k")) != value:  # type: ignore[union-attr]
            assert held in (None, limit) and time.monotonic() < deadline, held
            time.sleep(0.1)
    params = _answered(bench, "/api/params")
    assert {row["name"]: row["value"] for row in params}["egt_limit_k"] == value  # type: ignore[union-attr]


@pytest.mark.parametrize("impl", ["python", "c"])
def test_the_page_is_live_again_after_the_ecu_pauses_and_restarts(
    impl: str, tmp_path: Path
) -> None:
    limit = _known("egt_limit_k")
    with gsu.station(tmp_path, impl) as station:
        _live(station, 30)
        ecu = station.processes["ecu"]
        ecu.send_signal(signal.SIGSTOP)
        time.sleep(2.0)
        for path in ("/api/params", "/api/export", "/api/logbook"):
            started = time.monotonic()
            status, answer = _call(station, path)
            assert status in (503, 504) and "the ECU" in answer["error"], (path, answer)  # type: ignore[index]
            assert time.monotonic() - started < 3.0, path
        ecu.send_signal(signal.SIGCONT)
        assert _live(station, 10)["x_egt_limit_k"] == limit
        status, params = _call(station, "/api/params")
        assert status == 200, params
        ecu.terminate()
        ecu.wait(15)
        deadline = time.monotonic() + 5
        while not _call(station, "/api/state")[1]["ecu_silent"]:  # type: ignore[index]
            assert time.monotonic() < deadline
            time.sleep(0.1)
        with (tmp_path / "ecu-again.log").open("w") as log:
            station.processes["ecu"] = subprocess.Popen(
                ecu.args, cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
        assert _live(station, 30)["x_egt_limit_k"] == limit
        params = _answered(station, "/api/params")  # (a new ECU may pause as it comes up)
        assert {row["name"]: row["value"] for row in params}["egt_limit_k"] == limit  # type: ignore[union-attr]
    assert "Traceback" not in (tmp_path / "gsu.log").read_text()
