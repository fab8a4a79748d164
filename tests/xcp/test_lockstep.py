"""pyXCP attached to a lockstep `sil run`, the Python ECU and the C node with the C slave: a DAQ
list of 20 measurements on the control tick for more than 60 s of simulated time loses no sample
and gives, tick for tick, the values of the run's trace.csv; and the run's engine frames (every
frame but XCP's, in its tick and order) and its trace.csv are those of the same run with no
master.

A lockstep run goes as fast as its nodes: 40 times real time and more, far more DTOs a second
than any CAN bus carries. The master therefore joins with a loopback bus of its own whose socket
holds the burst (a large receive buffer), handed to pyXCP as its python-can bus."""

from __future__ import annotations

import math
import os
import random
import re
import socket
import threading
import time
from pathlib import Path

import pytest

from protocol.udp_loopback import LoopbackUdpMulticastBus
from sil import scenario
from sil.run.runner import RunOptions
from sil.run.runner import run as run_scenario

pytestmark = pytest.mark.slow
SO_RCVBUFFORCE = 33  # <asm-generic/socket.h>: beyond rmem_max, with CAP_NET_ADMIN
SCENARIO = """
description = "MRAC on the aero-thermal engine, a staircase around the trim, 70 s"
duration_s = 70
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "default"
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 85, 80, 75, 70, 75, 80, 85, 90, 95]
step_s = 7
"""
DAQ_NAMES = (
    "ticks", "mode", "fault_word", "speed_rpm", "speed_ref", "egt", "pump_voltage", "pump_duty",
    "pump_enable", "supply", "pump_current", "pump_health", "owner", "inputs_valid", "ap21",
    "ap22", "lambda", "theta21", "kx1", "kr",
)  # fmt: skip
# measurement -> (trace column, its scale, the raw range its frame carries)
EVERY_TICK = {
    "mode": ("ActuatorMode", 1, None),
    "pump_voltage": ("PumpVoltageTarget", 0.001, (0, 30000)),
    "pump_duty": ("PumpDuty", 0.01, None),
    "pump_enable": ("PumpEnable", 1, None),
    "speed_rpm": ("ShaftSpeed", 1, None),
    "egt": ("EGT", 0.1, None),
    "supply": ("SupplyVoltage", 0.001, None),
    "pump_current": ("PumpCurrent", 0.001, None),
}
STATUS = {  # EcuStatus, every 5 ticks
    "fault_word": ("FaultWord", 1, None),
    "speed_ref": ("ReferenceSpeed", 0.01, (0, 15000)),
    "pump_health": ("PumpHealth", 0.1, (0, 4095)),
    "owner": ("LoopOwner", 1, None),
    "inputs_valid": ("SensorsValid", 1, None),
}
TELEMETRY = {  # EcuTelemetry's multiplexer index at tick k: k % 13
    "ap21": (0, "Est_Ap21"), "ap22": (1, "Est_Ap22"), "lambda": (2, "Est_Lambda"),
    "theta21": (3, "Est_Theta21"), "kx1": (5, "Gain_Kx1"), "kr": (7, "Gain_Kr"),
}  # fmt: skip
XCP_LINE = re.compile(rb"^\(\S+\) \S+ 70[01]#")


def _bus_spec() -> tuple[str, int]:
    rng = random.Random(os.getpid() ^ time.time_ns())
    return f"239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}", rng.randrange(20000, 60000)


def _run(tmp: Path, name: str, master=None, impl: str = "python") -> tuple[dict, Path]:  # noqa: ANN001
    path = tmp / "staircase.toml"
    path.write_text(SCENARIO)
    group, port = _bus_spec()
    out = tmp / name
    thread = None
    if master is not None:
        thread = threading.Thread(target=master, args=(out, group, port), daemon=True)
        thread.start()
    options = RunOptions(
        scenario.load(path), out, bus=f"udp:{group}@{port}", plots=False, progress=False,
        ecu_impl=impl,
    )  # fmt: skip
    try:
        summary = run_scenario(options)
    finally:
        if thread is not None:
            master.run_over.set()
            thread.join(120)
    return summary, out


class Master:
    """pyXCP joining the run once its ECU listens: unlock, a DAQ list of 20 measurements on
    the control tick (types and addresses from the A2L), started; samples kept until the end."""

    def __init__(self, tools, a2l: dict) -> None:  # noqa: ANN001
        by_name = {m["name"]: m for m in a2l["measurements"]}
        self.daq = tools.daq([(n, by_name[n]["address"], by_name[n]["type"]) for n in DAQ_NAMES])
        self.tools = tools
        self.run_over = threading.Event()
        self.error: BaseException | None = None
        self.buffer = 0

    def __call__(self, out: Path, group: str, port: int) -> None:
        try:
            log = out / "ecu.log"
            while not (log.exists() and "xcp: " in log.read_text()):
                assert not self.run_over.is_set(), "the run ended before its ECU listened"
                time.sleep(0.01)
            bus = LoopbackUdpMulticastBus(group, port)
            bus.socket.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 256 << 20)
            self.buffer = bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            with self.tools.master("turbojet_udp", group, bus=bus, policy=self.daq) as x:
                x.connect()
                x.getCommModeInfo()
                x.cond_unlock("DAQ")
                self.daq.setup()
                self.daq.start()
                self.run_over.wait()
                time.sleep(1.0)  # the last DTOs out of the socket
            bus.shutdown()
        except BaseException as exc:  # reported by the test
            self.error = exc


def _engine_frames(can_log: Path, period_s: float) -> list[tuple[int, bytes]]:
    """(tick, frame) of every frame but XCP's: the recorder's times within a tick count the
    frames of the tick, XCP's among them, so the tick is what the two runs share."""
    out = []
    for line in can_log.read_bytes().splitlines():
        if XCP_LINE.match(line):
            continue
        stamp, rest = line.split(b" ", 1)
        out.append((math.floor(float(stamp[1:-1]) / period_s + 1e-6), rest))
    return out


def _trace(path: Path) -> tuple[dict[str, int], dict[int, list[str]]]:
    lines = path.read_text().splitlines()
    column = {h.split("[")[0]: k for k, h in enumerate(lines[0].split(","))}
    rows = {}
    for line in lines[1:]:
        cells = line.split(",")
        rows[int(cells[column["tick"]])] = cells
    return column, rows


@pytest.mark.parametrize("impl", ["python", "c"])
def test_daq_over_a_lockstep_run_is_its_trace_and_its_engine_frames_are_unchanged(
    impl, tmp_path, a2l, xcp_tools
):
    plain, out_a = _run(tmp_path, "plain", impl=impl)
    master = Master(xcp_tools, a2l)
    measured, out_b = _run(tmp_path, "measured", master, impl=impl)
    assert master.error is None, master.error
    for summary in (plain, measured):
        assert summary["status"] == "completed" and summary["missed_ticks"] == 0, summary

    # the run is the run without a master: its trace and every engine frame in its tick
    assert (out_b / "trace.csv").read_bytes() == (out_a / "trace.csv").read_bytes()
    assert _engine_frames(out_b / "can.log", 0.01) == _engine_frames(out_a / "can.log", 0.01)

    # no sample lost, over more than 60 s of simulated time
    daq = master.daq
    names = daq.names
    samples = [dict(zip(names, row, strict=True)) for _, _, row in daq.rows]
    ticks = [s["ticks"] for s in samples]
    assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))
    column, rows = _trace(out_a / "trace.csv")
    compared = [s for s in samples if s["ticks"] - 1 in rows]
    assert len(compared) >= 6000, (len(compared), master.buffer)

    print(
        f"DAQ: {len(samples)} samples, {len(compared)} in the trace, no gap; run without a "
        f"master {plain['wall_time_s']:.1f} s, with it {measured['wall_time_s']:.1f} s"
    )

    # sample n (the ECU's n-th tick done) is the trace's row of tick n - 1
    def check(s: dict, name: str, trace_column: str, scale: float, clamp) -> None:  # noqa: ANN001
        raw = s[name] if clamp is None else min(max(s[name], clamp[0]), clamp[1])
        cell = float(rows[s["ticks"] - 1][column[trace_column]])
        assert round(cell / scale) == raw, (s["ticks"], name, raw, cell)

    for s in compared:
        k = s["ticks"] - 1
        for name, (trace_column, scale, clamp) in EVERY_TICK.items():
            check(s, name, trace_column, scale, clamp)
        if k % 5 == 0:
            for name, (trace_column, scale, clamp) in STATUS.items():
                check(s, name, trace_column, scale, clamp)
        for name, (index, trace_column) in TELEMETRY.items():
            if k % 13 == index:
                cell = float(rows[k][column[trace_column]])
                assert math.isclose(s[name] * 2.0**-24, cell, rel_tol=1e-8, abs_tol=1e-7)
