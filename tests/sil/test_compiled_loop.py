"""The in-process run with the C ECU as one compiled loop (sil/run/compiled_loop.py) against the
same run through InProcessBus (``compiled_loop=False``, the Python nodes around the C core): the
same can.log and trace.csv byte for byte, the same summary but for its timings, on the shipped
scenarios' kinds (MRAC, PID and open loop; aero-thermal and fast plant; fault injections; an
engine that wears its pump from tick 0), and what an interrupted run keeps."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sil import scenario as scenarios
from sil.run.runner import RunOptions, run

TIMINGS = ("wall_time_s", "realtime_factor", "inproc_loop", "plots", "tick0_utc")


def _run(s, out: Path, compiled: bool, **kw) -> dict:
    opts = RunOptions(s, out, mode="inproc", ecu_impl="c", plots=False, progress=False,
                      compiled_loop=compiled, **kw)  # fmt: skip
    return run(opts)


@pytest.fixture
def same_run(tmp_path, first_difference):
    """Run a scenario in both loops, check they agree; the compiled run's summary."""

    def check(s, **kw) -> dict:
        compiled = _run(s, tmp_path / "compiled", True, **kw)
        python = _run(s, tmp_path / "python", False, **kw)
        assert compiled["inproc_loop"] == "compiled" and python["inproc_loop"] == "python"
        for name in ("can.log", "trace.csv"):
            a = (tmp_path / "compiled" / name).read_bytes()
            b = (tmp_path / "python" / name).read_bytes()
            assert a == b, f"{name}: {first_difference(a, b)}"
        python["run"].pop("compiled_loop")  # the one option the two runs differ by
        strip = {k: v for k, v in compiled.items() if k not in TIMINGS}
        assert strip == {k: v for k, v in python.items() if k not in TIMINGS}
        assert compiled["status"] == "completed"
        return compiled

    return check


@pytest.mark.parametrize(
    "name,duration_s",
    [
        ("thesis-5.3-mrac-aero", 45.0),  # MRAC, aero-thermal: past a noise block (4096 ticks)
        ("thesis-6.2-staircase-pid", 25.0),  # PID
        ("thesis-3.3-staircase", 20.0),  # open loop on the pump voltage
        ("thesis-5.2-mrac-fast", 30.0),  # the fast plant
        ("start-flameout-relight", 130.0),  # from rest: EcuStarter to the plant, relight, stop
    ],
)
def test_the_compiled_loop_writes_what_the_python_loop_writes(same_run, name, duration_s):
    s = scenarios.load(name)
    same_run(replace(s, duration_s=min(duration_s, s.duration_s)))


def test_fault_injections_and_pump_wear_as_in_the_python_loop(same_run):
    """The pump failure of sec. 6.3 (FaultInject frames, handled in Python at their tick), more
    faults on top, on an engine built with a worn pump that wears on (faults of the plant's own
    schedule from tick 0)."""
    s = scenarios.load("thesis-6.3-failure-mrac")
    faults = (
        *s.faults,
        scenarios.Fault(31.0, "SPEED_NOISE", 500.0),
        scenarios.Fault(31.5, "SPEED_NOISE", 0.0),
        scenarios.Fault(32.0, "EGT_OPEN_CIRCUIT", 1.0),
    )
    plant = replace(s.plant, pump_gain=0.97, pump_wear_per_s=1e-3, turbine_flow=0.98)
    summary = same_run(replace(s, duration_s=33.0, faults=faults, plant=plant))
    assert [f["tick"] for f in summary["faults_injected"]] == [3000, 3100, 3150, 3200]
    assert summary["faults"], "the open thermocouple is reported"


def test_two_compiled_runs_are_identical(tmp_path):
    s = scenarios.load("thesis-5.4-staircase")
    s = replace(s, duration_s=12.0)
    a = _run(s, tmp_path / "a", True, seed=7)
    b = _run(s, tmp_path / "b", True, seed=7)
    assert (tmp_path / "a" / "can.log").read_bytes() == (tmp_path / "b" / "can.log").read_bytes()
    assert a["tracking_rms_pct"] == b["tracking_rms_pct"]


BUS_FAULTED = """
duration_s = 1
[command]
base = 85
[[bus_fault]]
kind = "drop"
ids = ["PlantSensors"]
start_s = 0.5
rate = 0.3
duration_s = 0.2
"""


def test_bus_faults_and_the_python_ecu_take_the_python_loop(tmp_path):
    s = replace(scenarios.load("thesis-5.4-staircase"), duration_s=1.0)
    python_ecu = RunOptions(s, tmp_path / "py", mode="inproc", plots=False, progress=False)
    assert run(python_ecu)["inproc_loop"] == "python"
    faulted = scenarios.parse(BUS_FAULTED, "bus.toml", tmp_path)
    assert _run(faulted, tmp_path / "bus", True)["inproc_loop"] == "python"


def test_an_interrupted_compiled_run_keeps_every_frame_it_recorded(tmp_path, monkeypatch):
    """Ctrl-C between two calls of the loop (chunks of 1000 frames): the summary says so, and
    can.log holds the run's frames up to there, the last tick's included, as the full run has
    them."""
    s = replace(scenarios.load("thesis-5.3-mrac-aero"), duration_s=30.0)
    full = _run(s, tmp_path / "full", True)
    from sil.run import compiled_loop

    calls = {"n": 0}
    real = compiled_loop.run_frames

    def interrupted(*args):
        calls["n"] += 1
        if calls["n"] == 6:  # (1: compiled in the set-up; 2: the first noise block)
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(compiled_loop, "run_frames", interrupted)
    monkeypatch.setattr(compiled_loop, "CHUNK_FRAMES", 1000)
    cut = _run(s, tmp_path / "cut", True)
    assert cut["status"] == "aborted" and "Ctrl-C" in cut["abort_reason"]
    full_log = (tmp_path / "full" / "can.log").read_bytes()
    cut_log = (tmp_path / "cut" / "can.log").read_bytes()
    assert 300 <= cut["sim_time_s"] * 100 < full["sim_time_s"] * 100
    assert len(cut_log) > 0 and full_log.startswith(cut_log)
    summary = json.loads((tmp_path / "cut" / "summary.json").read_text())
    assert summary["status"] == "aborted"


def test_a_campaign_case_gives_the_same_rows_in_the_compiled_loop():
    """The campaign's probe (no files): the rows of a case with the C ECU, compiled loop against
    Python loop, equal value for value; the plant's truth per tick as the loop kept it."""
    from sil.campaign.case import run_case

    s = scenarios.load("thesis-6.3-failure-mrac")
    plant = replace(s.plant, pump_gain=1.05, compressor_efficiency=0.98)
    s = replace(s, duration_s=32.0, plant=plant)
    compiled = run_case(s, ecu_impl="c")
    python = run_case(s, ecu_impl="c", compiled_loop=False)
    columns = ("speed_pct", "ref_pct", "n_pct", "egt_k", "p3_pa", "thrust_n", "flags")
    columns += ("fault_word", "owner", "mode", "pump_v")
    for name in columns:
        a, b = compiled.column(name), python.column(name)
        assert len(a) == len(b) == compiled.ticks, name
        assert np.array_equal(a, b, equal_nan=True), name
    assert not np.isnan(compiled.column("n_pct")).any()
