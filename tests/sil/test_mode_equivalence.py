"""Every shipped scenario flies alike in process and in lockstep on the loopback bus: the same
can.log, byte for byte, so every event (a fault at tick 0, the Demands before the first tick, a
start, a stop) reaches every node at the same tick in both modes.

The one difference by design between the two modes is in no shipped scenario: bus faults
(``[[bus_fault]]``). On a bus they act in the fault bridge between two buses, where a dropped
frame costs the node waiting for it a wall-clock guard time and the run is recorded on the
plant's side, after the injector; in process they act on the FIFO of frames. The bus-fault
campaign tests cover them.

Each scenario is cut (``cut``) so that the whole test stays within a couple of minutes: to 25 s,
or to 3 s past its last fault; a run from rest to 32 s, with its stop 6 s before the end so that
it starts, runs and stops."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import pytest

from sil import scenario as scenarios
from sil.run.run_record import scenario_text
from sil.run.runner import RunOptions, run
from sil.scenario import Scenario

CUT_S = 25.0  # every scenario is cut to this, or to 3 s past its last fault
FROM_REST_S = 32.0  # a start takes about 21 s: then the stop, 6 s before the end
STARTS = ("start_time_s", "start_egt_peak_K", "start_abort", "start_abort_s", "relights")


def cut(s: Scenario) -> Scenario:
    """The scenario shortened for the test (see the module docstring)."""
    last_fault = max((f.time_s for f in s.faults), default=0.0)
    duration = min(s.duration_s, max(CUT_S, last_fault + 3.0))
    if s.plant.standstill:
        duration = min(s.duration_s, max(duration, FROM_REST_S))
    stop = None if s.stop_s is None else min(s.stop_s, duration - 6.0)
    return replace(s, duration_s=duration, stop_s=stop)


def _fly(s: Scenario, out, mode: str, **options) -> dict:
    return run(RunOptions(s, out, mode=mode, plots=False, progress=False, **options))


@pytest.mark.slow
@pytest.mark.parametrize("name", scenarios.shipped_names())
def test_a_shipped_scenario_gives_one_can_log_in_process_and_in_lockstep(
    name, tmp_path, udp_spec, first_difference
):
    s = cut(scenarios.load(name))
    inproc = _fly(s, tmp_path / "inproc", "inproc")
    bus = _fly(s, tmp_path / "bus", "lockstep", bus=udp_spec())
    assert inproc["status"] == bus["status"] == "completed", bus["abort_reason"]
    assert bus["missed_ticks"] == 0
    logs = [(tmp_path / m / "can.log").read_bytes() for m in ("inproc", "bus")]
    assert first_difference(*logs) is None
    assert bus["faults_injected"] == inproc["faults_injected"]
    if s.plant.standstill:  # it started, ran and stopped, or aborted its start, alike
        assert bus["start_abort"] == inproc["start_abort"]
        assert bus["start_time_s"] == inproc["start_time_s"]


@pytest.mark.slow
def test_a_varied_engine_flies_alike_on_the_bus(tmp_path, udp_spec, first_difference):
    """Every [plant] variation reaches the plant process (sil plant's options)."""
    s = cut(scenarios.load("thesis-5.4-staircase"))
    plant = replace(
        s.plant, compressor_efficiency=0.97, compressor_flow=1.02, turbine_efficiency=0.98,
        turbine_flow=0.99, pump_gain=0.9, pump_wear_per_s=0.001, speed_noise_rpm=35.0,
        speed_bias_rpm=-40.0, egt_noise_K=2.0, egt_bias_K=5.0,
    )  # fmt: skip
    s = replace(s, plant=plant, duration_s=10.0)
    inproc = _fly(s, tmp_path / "inproc", "inproc")
    bus = _fly(s, tmp_path / "bus", "lockstep", bus=udp_spec())
    assert inproc["status"] == bus["status"] == "completed"
    logs = [(tmp_path / m / "can.log").read_bytes() for m in ("inproc", "bus")]
    assert first_difference(*logs) is None
    nominal = _fly(replace(s, plant=scenarios.load("thesis-5.4-staircase").plant),
                   tmp_path / "nominal", "inproc")  # fmt: skip
    assert nominal["tracking_rms_pct"] != inproc["tracking_rms_pct"]  # another engine indeed


START_SCENARIOS = {  # a start from rest, cut (s) past its start, or its relight, or its abort
    "start-nominal": 24.0,
    "start-no-light": 22.0,
    "start-hot-day": 24.0,
    "start-cold-day": 24.0,
    "start-flameout-relight": 36.0,
}


@pytest.mark.slow
def test_the_starts_in_real_time_are_the_lockstep_starts(tmp_path, udp_spec):
    """The start scenarios in real time (each node on its own clock; all five at once, as they
    take their simulated time in wall time) against lockstep: the start time within 1 s, the
    EGT peak within 30 K, the same abort and relights."""
    runs = {}
    for name, seconds in START_SCENARIOS.items():
        s = scenarios.load(name)
        s = replace(s, duration_s=seconds, stop_s=None)
        path = tmp_path / f"{name}.toml"
        path.write_text(scenario_text(s, s.seed))
        out = tmp_path / name / "realtime"
        runs[name] = (s, out, subprocess.Popen(
            [sys.executable, "-m", "sil.cli", "run", str(path), "--mode", "realtime",
             "--bus", udp_spec(), "--out", str(out), "--no-plots"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        ))  # fmt: skip
    for name, (_, _, proc) in runs.items():
        _, stderr = proc.communicate(timeout=180)
        assert proc.returncode == 0, f"{name}: {stderr}"
    for name, (s, out, _) in runs.items():
        realtime = json.loads((out / "summary.json").read_text())
        lockstep = _fly(s, tmp_path / name / "lockstep", "lockstep", bus=udp_spec())
        figures = {k: (lockstep.get(k), realtime.get(k)) for k in STARTS}
        assert realtime["start_abort"] == lockstep["start_abort"], (name, figures)
        assert realtime["relights"] == lockstep["relights"], (name, figures)
        if lockstep["start_time_s"] is None:
            assert realtime["start_time_s"] is None, (name, figures)
        else:
            assert abs(realtime["start_time_s"] - lockstep["start_time_s"]) <= 1.0, (name, figures)
        assert abs(realtime["start_egt_peak_K"] - lockstep["start_egt_peak_K"]) <= 30.0, (
            name, figures
        )  # fmt: skip
