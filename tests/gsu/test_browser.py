"""The ground-support page in a real browser (headless Chromium) against a plant and an ECU
running in real time: the dashboard's speed follows the engine (read from the bus by the test
itself), a test function at rest spins the rotor for its time, start brings the engine to idle, a
throttle change moves it, a test function is refused while it runs, a refused parameter write
shows the ECU's reason, the parameter file goes out and comes back in through the ECU's checks,
stop cools it, the logbook counts the run, a recording is written.
Screenshots of each page go to $GSU_SCREENSHOTS (docs/gsu/ for the docs) or the test's folder."""

from __future__ import annotations

import json
import os
import re
import threading
import time
from pathlib import Path

import msgpack
import pytest

from ecu.firmware import RPM_PER_PCT
from ecu.service import storage
from ecu.service.param_table import BY_NAME
from protocol.bus import open_bus
from protocol.dbc import load_database

pytestmark = pytest.mark.slow

IDLE_PCT = 40.0  # above this the engine runs on its own
RUN_S = 60.0  # from start to RUN, real time
COOL_S = 150.0  # from stop to OFF


class BusWatch:
    """The engine's speed and EGT as the sensor frames carry them, and the ECU's state as its
    status frames say, read by the test from the bus itself."""

    def __init__(self, spec: str) -> None:
        self.bus = open_bus(spec)
        db = load_database()
        self.sensors = db.get_message_by_name("PlantSensors")
        self.status = db.get_message_by_name("EcuStatus")
        self.rows: list[tuple[float, float, float]] = []  # wall s, rpm, EGT K
        self.states: list[tuple[float, str]] = []  # wall s, ECU mode
        self._go = True
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while self._go:
            msg = self.bus.recv(0.1)
            if msg is None:
                continue
            if msg.arbitration_id == self.sensors.frame_id:
                d = self.sensors.decode(bytes(msg.data))
                self.rows.append((time.time(), d["ShaftSpeed"], d["EGT"]))
            elif msg.arbitration_id == self.status.frame_id:
                mode = self.status.decode(bytes(msg.data))["EcuMode"]
                self.states.append((time.time(), str(mode)))

    def speeds_since(self, t0: float) -> list[float]:
        return [rpm / RPM_PER_PCT for t, rpm, _ in list(self.rows) if t >= t0]

    def the_run(self) -> tuple[float, float, float]:
        """The run's seconds in RUN (from its status frames), its highest speed (%N) and EGT."""
        in_run = [t for t, mode in self.states if mode == "RUN"]
        rows = [r for r in self.rows if in_run[0] <= r[0] <= in_run[-1]]
        seconds = in_run[-1] - in_run[0]
        return seconds, max(r[1] for r in rows) / RPM_PER_PCT, max(r[2] for r in rows)

    def close(self) -> None:
        self._go = False
        self._thread.join(2)
        self.bus.shutdown()


def _number(page, testid: str) -> float:  # noqa: ANN001 (Playwright's Page)
    text = page.get_by_test_id(testid).inner_text().strip().split(" ")[0]
    return float(text) if text not in ("-", "") else float("nan")


def _seconds(text: str) -> float:
    """'0 h 1 min 12 s' in seconds."""
    h, m, sec = re.fullmatch(r"(\d+) h (\d+) min (\d+) s", text.strip()).groups()
    return 3600 * int(h) + 60 * int(m) + int(sec)


def _wait(what: str, condition, timeout_s: float, page=None) -> None:  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.2)
    state = page.get_by_test_id("state").inner_text() if page is not None else "?"
    pytest.fail(f"{what}: not within {timeout_s:g} s (state on the page: {state})")


def _shot(page, folder: Path, name: str) -> None:  # noqa: ANN001
    page.wait_for_timeout(300)
    page.screenshot(path=str(folder / f"{name}.png"), full_page=True)


def _follows(page, watch: BusWatch) -> None:  # noqa: ANN001
    """The page's speed is one the sensor frames carried within the last second."""
    for _ in range(5):
        t0 = time.time() - 1.0
        shown = _number(page, "speed")
        seen = watch.speeds_since(t0)
        assert seen, "no sensor frame on the bus"
        assert min(seen) - 0.15 <= shown <= max(seen) + 0.15, (shown, min(seen), max(seen))
        time.sleep(0.3)


def _export_and_import(page, bench, tmp_path: Path) -> None:  # noqa: ANN001
    """The parameter file exported holds the ECU's values; imported with one value changed, one
    over its limit and one name this ECU has not, it writes the first, shows the ECU's refusal
    of the second and names the third."""
    with page.expect_download() as download:
        page.get_by_test_id("export").click()
    exported = json.loads(Path(download.value.path()).read_text())
    on_ecu = {row["name"]: row["value"] for row in bench.api("/api/params")}
    assert {k: v["value"] for k, v in exported["parameters"].items()} == on_ecu
    assert exported["parameters"]["egt_limit_k"] == {"value": on_ecu["egt_limit_k"], "unit": "K"}
    edited = dict(exported, parameters={**exported["parameters"],
                                        "egt_limit_k": {"value": 1230.0, "unit": "K"},
                                        "egt_kp": {"value": 5.0, "unit": "V/K"},
                                        "no_such_parameter": {"value": 1.0}})  # fmt: skip
    path = tmp_path / "engine.json"
    path.write_text(json.dumps(edited))
    page.get_by_test_id("import").set_input_files(str(path))
    message = page.get_by_test_id("params-msg")
    _wait("the import", lambda: "engine.json: 1 written" in message.inner_text(), 30, page)
    assert "refused: egt_kp = 5: outside its limits [0, 1] V/K (ERR_OUT_OF_RANGE)" in \
        message.inner_text()  # fmt: skip
    assert "not in this ECU: no_such_parameter" in message.inner_text()
    after = {row["name"]: row["value"] for row in bench.api("/api/params")}
    assert after["egt_limit_k"] == pytest.approx(1230.0) and after["egt_kp"] == on_ecu["egt_kp"]


def test_a_run_from_the_page(bench, browser, tmp_path) -> None:  # noqa: ANN001
    shots = Path(os.environ.get("GSU_SCREENSHOTS") or tmp_path)
    shots.mkdir(parents=True, exist_ok=True)
    watch = BusWatch(bench.spec)
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    try:
        page.goto(bench.url)
        _wait("the dashboard shows the engine at rest",
              lambda: page.get_by_test_id("state").inner_text() == "OFF", 20, page)  # fmt: skip
        _follows(page, watch)

        page.goto(bench.url + "#log")
        page.get_by_test_id("logbook-reload").click()
        _wait("the logbook is read", lambda: page.get_by_test_id("logbook-runs").inner_text()
              not in ("-", ""), 15, page)  # fmt: skip
        runs_before = int(page.get_by_test_id("logbook-runs").inner_text())

        page.goto(bench.url + "#record")
        page.get_by_test_id("record-start").click()
        _wait("recording", lambda: "recording:" in page.get_by_test_id("record-state").inner_text(),
              5, page)  # fmt: skip

        # start: refused while locked, then unlocked, confirmed, to idle
        page.goto(bench.url + "#run")
        page.get_by_test_id("start").click()
        page.get_by_test_id("start-confirm").click()
        run_msg = page.get_by_test_id("run-msg")
        _wait("a locked ECU refuses", lambda: "locked" in run_msg.inner_text(), 10, page)
        page.get_by_test_id("unlock").click()
        _wait("unlocked", lambda: "unlocked" in page.get_by_test_id("link-ecu").inner_text(), 10)

        # a test function at rest: the starter spins the shaft for its time, then the ECU ends it
        page.goto(bench.url + "#tests")
        page.locator("#starter-level").fill("25")
        page.locator("#starter-s").fill("2")
        spun_from = time.time()
        page.get_by_test_id("test-starter").click()
        active = page.get_by_test_id("test-active")
        _wait("the starter test runs", lambda: active.inner_text() == "STARTER", 5, page)
        _wait("the ECU ends it", lambda: active.inner_text() == "NONE", 8, page)
        assert time.time() - spun_from >= 2.0
        assert max(watch.speeds_since(spun_from)) > 1.0  # %N: the starter turned the rotor
        _wait("the rotor at rest again", lambda: max(watch.speeds_since(time.time() - 0.5),
              default=1) < 0.5, 60, page)  # fmt: skip

        page.goto(bench.url + "#run")
        page.get_by_test_id("start").click()
        assert page.get_by_test_id("confirm").is_visible()
        page.get_by_test_id("start-confirm").click()
        _wait("the engine runs", lambda: page.get_by_test_id("state").inner_text() == "RUN",
              RUN_S, page)  # fmt: skip
        _wait("idle", lambda: _number(page, "speed") > IDLE_PCT, 20, page)
        _follows(page, watch)
        idle = _number(page, "speed")

        # a throttle change moves it
        page.get_by_test_id("throttle").fill("70")
        page.get_by_test_id("throttle-set").click()
        _wait("the engine accelerates", lambda: _number(page, "speed") > idle + 10, 30, page)
        _follows(page, watch)
        page.goto(bench.url + "#dashboard")
        _wait("a chart's worth", lambda: True, 1)
        _shot(page, shots, "dashboard")

        # test functions are refused while the engine runs
        page.goto(bench.url + "#tests")
        page.get_by_test_id("test-glow").click()
        test_msg = page.get_by_test_id("test-msg")
        _wait("the test refused", lambda: "refused" in test_msg.inner_text(), 10, page)
        assert "glow test: the ECU's state refuses it (ERR_ACCESS_DENIED)" in test_msg.inner_text()
        _shot(page, shots, "tests")

        # a refused parameter write shows the ECU's reason
        page.goto(bench.url + "#params")
        page.get_by_test_id("param-input-egt_limit_k").wait_for(timeout=30_000)
        page.get_by_test_id("param-input-egt_limit_k").fill("1500")
        page.get_by_test_id("param-write-egt_limit_k").click()
        message = page.get_by_test_id("param-msg-egt_limit_k")
        _wait("the refusal", lambda: "refused" in message.inner_text(), 10, page)
        assert "outside its limits [800, 1400] K" in message.inner_text()
        assert "ERR_OUT_OF_RANGE" in message.inner_text()
        page.locator("#params-filter").fill("egt")  # (the table's filter: the EGT's parameters)
        _shot(page, shots, "parameters")
        page.locator("#params-filter").fill("")
        _export_and_import(page, bench, tmp_path)
        page.get_by_test_id("store").click()
        stored = page.get_by_test_id("params-msg")
        _wait("the set stored to flash", lambda: stored.inner_text() == "stored to flash", 30, page)
        in_flash = msgpack.unpackb(storage.load(bench.folder / "ecu.flash").payload)
        assert in_flash["egt_limit_k"] == BY_NAME["egt_limit_k"].to_raw(1230.0)

        # stop cools it
        page.goto(bench.url + "#run")
        _shot(page, shots, "start-stop")
        egt_at_stop = _number(page, "egt")
        page.get_by_test_id("stop").click()
        _wait("the engine stops", lambda: page.get_by_test_id("state").inner_text() == "OFF",
              COOL_S, page)  # fmt: skip
        assert _number(page, "egt") < egt_at_stop - 100

        # the logbook counts the run; the recording is written
        page.goto(bench.url + "#log")
        page.get_by_test_id("logbook-reload").click()
        _wait("the logbook counts the run",
              lambda: page.get_by_test_id("logbook-runs").inner_text() == str(runs_before + 1),
              15, page)  # fmt: skip
        seconds, top_speed, top_egt = watch.the_run()
        shown = page.get_by_test_id("logbook-time").inner_text()
        assert abs(_seconds(shown) - seconds) <= 1.5, (shown, seconds)
        assert _number(page, "logbook-speed") == pytest.approx(top_speed, abs=0.2)
        assert _number(page, "logbook-egt") == pytest.approx(top_egt, abs=1.0)
        assert page.get_by_test_id("logbook-shutdown").inner_text() == "OPERATOR_STOP"
        _shot(page, shots, "faults-logbook")
        page.goto(bench.url + "#record")
        page.get_by_test_id("record-stop").click()
        record_msg = page.get_by_test_id("record-msg")
        _wait("the recording written", lambda: ".mf4" in record_msg.inner_text(), 30, page)
        _shot(page, shots, "record")
        written = list(bench.folder.glob("gsu-*.mf4"))
        assert len(written) == 1 and written[0].stat().st_size > 100_000

    finally:
        page.close()
        watch.close()
