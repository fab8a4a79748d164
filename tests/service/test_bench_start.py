"""A bench as an engineer sets one up: the plant and the ECU as separate real-time processes on
a loopback bus with no Demand frames, the console on the ECU's pseudo-terminal. `sil console
PORT arm` starts the engine from 0 rpm to idle, `throttle 70` takes it to 70 %N, `stop` shuts it
down and cools it; the console's live record shows each step, and the ECU's own frames on the
bus show every sequencer state in order."""

from __future__ import annotations

import time

import pytest

from ecu import modes as M
from ecu import start_sequencer as Q
from protocol.bus import open_bus, unique_udp_spec
from protocol.codec import Codec

pytestmark = pytest.mark.slow


class Frames:
    """Every EcuStarter and EcuStatus frame of the bench's bus, as the test's own listener."""

    def __init__(self, spec) -> None:
        codec = Codec()
        self.bus = open_bus(spec)
        self.starter, self.status = codec["EcuStarter"], codec["EcuStatus"]
        self.seq_states: list[int] = []
        self.modes: list[int] = []
        self._raw = [0] * 8

    def drain(self) -> None:
        while (msg := self.bus.recv(0.0)) is not None:
            if msg.arbitration_id == self.starter.frame_id:
                self.starter.unpack_raw(msg.data, self._raw)
                state = self._raw[3]
                if not self.seq_states or self.seq_states[-1] != state:
                    self.seq_states.append(state)
            elif msg.arbitration_id == self.status.frame_id:
                self.status.unpack_raw(msg.data, self._raw)
                if not self.modes or self.modes[-1] != self._raw[0]:
                    self.modes.append(self._raw[0])


def _until(console, frames: Frames, port: str, done, limit_s: float) -> dict:
    """Console live samples until ``done(sample)``; the last sample."""
    deadline = time.monotonic() + limit_s
    while True:
        frames.drain()
        sample = console.live(port, 1)[0]
        if done(sample) or time.monotonic() > deadline:
            return sample
        time.sleep(0.5)


def test_console_starts_throttles_and_stops_an_engine_on_a_bench(
    tmp_path, sil_process, console, stderr_line
):
    spec = unique_udp_spec()
    frames = Frames(spec)
    plant = sil_process("plant", "--bus", str(spec), "--realtime", "--standstill", cwd=tmp_path)
    ecu = sil_process(
        "ecu", "--bus", str(spec), "--mode", "realtime", "--serial", "pty", cwd=tmp_path
    )
    try:
        port = stderr_line(ecu, "service port: ")
        at_rest = _until(console, frames, port, lambda v: v["inputs_valid"] == 1, 30)
        assert at_rest["mode"] == M.OFF and at_rest["speed"] < 1.0
        assert at_rest["demand_source"] == 2  # NONE: no Demand frames, bench not engaged

        t0 = time.monotonic()
        assert console(port, "arm") == {"mode_before": "OFF"}
        idle = _until(
            console, frames, port, lambda v: v["mode"] == M.RUN and v["seq_state"] == Q.RUN, 60
        )
        start_s = time.monotonic() - t0
        assert idle["mode"] == M.RUN, idle
        assert idle["demand_source"] == 1 and idle["seq_reason"] == Q.NO_ABORT  # BENCH
        idle = _until(console, frames, port, lambda v: abs(v["speed"] - v["demand"]) < 3.0, 20)
        assert 30.0 < idle["speed"] < 45.0, idle

        t1 = time.monotonic()
        assert console(port, "throttle", "70") == {"demand_pct": 70.0, "source": "BENCH"}
        at_70 = _until(console, frames, port, lambda v: abs(v["speed"] - 70.0) < 1.0, 30)
        throttle_s = time.monotonic() - t1
        assert abs(at_70["speed"] - 70.0) < 1.0 and at_70["egt"] < at_70["egt_start_limit"]

        t2 = time.monotonic()
        assert console(port, "stop") == {"mode_before": "RUN"}
        cooled = _until(console, frames, port, lambda v: v["mode"] == M.OFF, 150)
        stop_s = time.monotonic() - t2
        assert cooled["mode"] == M.OFF and cooled["speed"] < 1.0
        assert cooled["egt"] < 373.15 + 15  # cooled under 100 degC (and its re-arm margin)
        frames.drain()
        faults = console(port, "faults")
    finally:
        for proc in (ecu, plant):
            proc.terminate()
        for proc in (ecu, plant):
            proc.wait(10)
        frames.bus.shutdown()

    # EcuStarter goes out in ARMED and SHUTDOWN: the start's steps, then the stop's
    start = [Q.SPIN_UP, Q.IGNITION, Q.RAMP, Q.STABILISE]
    stop = [Q.SPOOL_DOWN, Q.COOL_DOWN, Q.DONE]
    assert frames.seq_states[: len(start)] == start, frames.seq_states
    assert frames.seq_states[len(start) : len(start) + len(stop)] == stop, frames.seq_states
    assert frames.modes[:5] == [M.OFF, M.ARMED, M.RUN, M.SHUTDOWN, M.OFF], frames.modes
    names = [f["name"] for f in faults]
    assert "DEMAND_SOURCE_BENCH" in names and not any(n.startswith("START_ABORT") for n in names)
    assert start_s < 40.0
    print(
        f"bench: arm to idle {start_s:.1f} s at {idle['speed']:.1f} %N, throttle 70 in "
        f"{throttle_s:.1f} s (EGT {at_70['egt']:.0f} K), stop to OFF in {stop_s:.1f} s "
        f"(EGT {cooled['egt']:.0f} K)"
    )
