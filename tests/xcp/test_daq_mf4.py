"""DAQ recorded into MF4 (sil/record/xcp_record.py, `sil xcp record`): pyXCP the master, the A2L's
names, units and conversions on the channels.

(a) The recorder on a lockstep run: every sample's physical values, as asammdf reads them from
the MF4, are the run's trace.csv at that tick, and the time axis is the ECU's clock (simulated
time). (b) `sil xcp record` against a real-time ECU at rest: the channels, units, conversions
(a value table's texts), 100 samples a second on the control tick."""

from __future__ import annotations

import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from protocol.udp_loopback import LoopbackUdpMulticastBus
from sil import scenario
from sil.record import xcp_record
from sil.record.a2l import read_a2l
from sil.run.runner import RunOptions
from sil.run.runner import run as run_scenario

pytestmark = pytest.mark.slow
asammdf = pytest.importorskip("asammdf")
SO_RCVBUFFORCE = 33
SCENARIO = """
description = "MRAC on the aero-thermal engine, a staircase around the trim, 40 s"
duration_s = 40
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "default"
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 85, 80, 85, 90]
step_s = 8
"""
# measurement -> (trace column, the raw range its frame carries, the ticks its frame is sent)
EVERY_TICK = {
    "speed_rpm": ("ShaftSpeed", None),
    "egt": ("EGT", None),
    "pump_voltage": ("PumpVoltageTarget", (0.0, 30.0)),
    "pump_duty": ("PumpDuty", None),
    "supply": ("SupplyVoltage", None),
}
UNITS = {"ticks": "", "mode": "", "speed_rpm": "rpm", "egt": "K", "pump_voltage": "V",
         "pump_duty": "%", "supply": "V", "speed_ref": "%", "ap21": "1/s2"}  # fmt: skip


def _a2l(sil, tmp: Path) -> Path:
    path = tmp / "turbojet_ecu.a2l"
    done = sil("a2l", "--out", str(path), timeout=None)
    assert done.returncode == 0, done.stderr
    return path


def _trace(path: Path) -> tuple[dict[str, int], dict[int, list[float]]]:
    lines = path.read_text().splitlines()
    column = {h.split("[")[0]: k for k, h in enumerate(lines[0].split(","))}
    rows = {}
    for line in lines[1:]:
        cells = [float(c) for c in line.split(",")]
        rows[int(cells[column["tick"]])] = cells
    return column, rows


def test_daq_of_a_lockstep_run_into_mf4_is_its_trace(tmp_path, sil, udp_group):
    a2l_path = _a2l(sil, tmp_path)
    a2l = read_a2l(a2l_path)
    names = ["ticks", "mode", *EVERY_TICK, "speed_ref", "ap21"]
    measurements = xcp_record.pick(a2l, names)
    group, port = udp_group
    bus = LoopbackUdpMulticastBus(group, port)
    bus.socket.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 256 << 20)  # the run's bursts
    stop = threading.Event()
    result: dict = {}

    def master() -> None:
        try:
            result["recording"] = xcp_record.record(
                bus, a2l, measurements, 600, stop=stop, connect_timeout_s=120
            )
        except BaseException as exc:  # reported by the test
            result["error"] = exc

    thread = threading.Thread(target=master, daemon=True)
    thread.start()
    path = tmp_path / "staircase.toml"
    path.write_text(SCENARIO)
    out = tmp_path / "run"
    try:
        summary = run_scenario(
            RunOptions(
                scenario.load(path), out, bus=f"udp:{group}@{port}", plots=False, progress=False
            )  # fmt: skip
        )
    finally:
        time.sleep(1.0)  # the last DTOs out of the socket
        stop.set()
        thread.join(120)
        bus.shutdown()
    assert "error" not in result, result.get("error")
    assert summary["status"] == "completed" and summary["missed_ticks"] == 0, summary
    recording = result["recording"]
    mf4 = tmp_path / "daq.mf4"
    xcp_record.write(mf4, recording, a2l, a2l_path, 0)

    m = asammdf.MDF(mf4)
    assert abs(m.header.start_time.timestamp() - recording.start_us / 1e6) < 1e-6
    assert m.groups[0].channel_group.acq_name == "control tick"
    physical = {n: m.get(n) for n in names}
    for n in names:
        assert physical[n].unit == UNITS[n], n
        assert physical[n].comment == a2l.measurements[n].comment
    assert list(physical["mode"].samples[-3:]) == [b"RUN"] * 3  # the value table's texts
    ticks = m.get("ticks").samples.astype(int)
    t = physical["ticks"].timestamps
    assert t[0] == 0.0 and (ticks == np.arange(ticks[0], ticks[0] + len(ticks))).all()
    # the time axis: the ECU's clock, its ticks of 10 ms (simulated time in lockstep)
    assert np.allclose(t, (ticks - ticks[0]) * 0.01, atol=1e-6)

    column, rows = _trace(out / "trace.csv")
    compared, last = 0, -1
    worst: dict[str, float] = {}

    def check(tick: int, name: str, trace_column: str, value: float, bound: float) -> None:
        recorded = rows[tick - 1][column[trace_column]]
        assert abs(value - recorded) <= bound, (tick, name, value, recorded)
        worst[name] = max(worst.get(name, 0.0), abs(value - recorded))

    modes = m.get("mode", raw=True).samples
    for i, tick in enumerate(ticks):
        k = tick - 1  # sample n (the ECU's n-th tick done) is the trace's row of tick n - 1
        if k not in rows:
            continue
        compared, last = compared + 1, k
        for name, (trace_column, clamp) in EVERY_TICK.items():
            value = float(physical[name].samples[i])
            if clamp is not None:
                value = min(max(value, clamp[0]), clamp[1])
            check(tick, name, trace_column, value, 1e-9)
        check(tick, "mode", "ActuatorMode", float(modes[i]), 0)
        if k % 5 == 0:  # EcuStatus
            value = float(physical["speed_ref"].samples[i])
            check(tick, "speed_ref", "ReferenceSpeed", value, 1e-9)
        if k % 13 == 0:  # EcuTelemetry, index 0
            check(tick, "ap21", "Est_Ap21", float(physical["ap21"].samples[i]), 1e-8)
    print(f"DAQ MF4: {len(ticks)} samples, {compared} compared with trace.csv; largest "
          f"difference per measurement: {worst}")  # fmt: skip
    # the master joins when the machine lets it (its DAQ set-up is a few dozen commands, each
    # answered at a tick): 10 s at least, more than a step of the staircase, on to the run's end
    assert compared >= 1000 and last >= max(rows) - 1, (compared, last, max(rows))
    assert set(worst) == set(names) - {"ticks"}
    m.close()


def test_sil_xcp_record_writes_the_a2ls_names_units_and_conversions(
    tmp_path, sil, sil_process, udp_group
):
    a2l_path = _a2l(sil, tmp_path)
    group, port = udp_group
    bus = f"udp:{group}@{port}"
    plant = sil_process("plant", "--bus", bus, "--realtime", "--standstill")
    ecu = sil_process("ecu", "--bus", bus, "--mode", "realtime")
    out = tmp_path / "rest.mf4"
    try:
        done = sil(
            "xcp", "record", "--bus", bus, "--a2l", str(a2l_path), "--measure", "ticks", "mode",
            "egt", "supply", "--measure", "speed_rpm", "ap21", "--seconds", "2", "--out", str(out),
            "--connect-timeout", "60", timeout=180,
        )  # fmt: skip
    finally:
        for proc in (ecu, plant):
            proc.terminate()
        for proc in (ecu, plant):
            proc.communicate(timeout=20)
    assert done.returncode == 0, done.stderr
    assert done.stdout == ""
    (line,) = done.stderr.splitlines()
    assert line.startswith(f"sil xcp record: {out}: ") and "measurements on event 0" in line

    m = asammdf.MDF(out)
    assert abs(m.header.start_time.timestamp() - time.time()) < 120
    g = m.groups[0]
    assert [c.name for c in g.channels] == ["time", "ticks", "mode", "egt", "supply",
                                            "speed_rpm", "ap21"]  # fmt: skip
    assert g.channel_group.acq_source.name == "turbojet_ecu"
    ticks = m.get("ticks").samples.astype(int)
    assert len(ticks) >= 150 and (np.diff(ticks) == 1).all()  # no sample lost
    t = m.get("ticks").timestamps
    assert t[0] == 0.0 and 0.0095 < np.mean(np.diff(t)) < 0.0105  # the ECU's 100 Hz clock
    # the A2L's conversions: a value table's texts, LINEAR factors, the units
    assert set(m.get("mode").samples) <= {b"OFF", b"ARMED"}
    egt, egt_raw = m.get("egt"), m.get("egt", raw=True)
    assert egt.unit == "K" and np.allclose(egt.samples, egt_raw.samples * 0.1)
    assert 270 < np.mean(egt.samples) < 310  # a cold engine at rest
    supply = m.get("supply")
    assert supply.unit == "V" and abs(np.mean(supply.samples) - 22.2) < 0.5  # the battery
    ap21 = m.get("ap21")
    assert ap21.unit == "1/s2"
    assert math.isclose(ap21.samples[0], m.get("ap21", raw=True).samples[0] * 2.0**-24)
    m.close()


def test_unknown_measurements_and_unreadable_a2ls_are_refused_in_one_line(tmp_path, sil):
    a2l_path = _a2l(sil, tmp_path)
    bad = tmp_path / "bad.a2l"
    bad.write_text(a2l_path.read_text()[:20000])
    for a2l, measure, expected in (
        (a2l_path, "egtx", "--measure: egtx: no such MEASUREMENT in the A2L"),
        (bad, "egt", f"--a2l {bad}: pya2ldb's parser: "),
        (tmp_path / "none.a2l", "egt", "no such file"),
    ):
        done = sil(
            "xcp", "record", "--bus", "virtual:none", "--a2l", str(a2l), "--measure", measure,
            "--seconds", "1", "--out", str(tmp_path / "x.mf4"), timeout=120,
        )  # fmt: skip
        assert done.returncode == 2, done.stderr
        assert done.stdout == ""
        (line,) = done.stderr.splitlines()
        assert line.startswith("sil xcp record: ") and expected in line, line
    assert not (tmp_path / "x.mf4").exists()
