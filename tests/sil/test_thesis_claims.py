"""The document's chapter-6 claims in our own runs (aero-thermal plant, shipped scenarios, in
process): the MRAC tracks its reference model on the 70-100 %N staircase at least 2x better than
the PID, and after the pump's effectiveness halves at 30 s it keeps tracking (last 60 s within
1.5x of before the failure) while Lambda-hat settles within 15 % of half its value."""

from pathlib import Path

import numpy as np
import pytest

from sil import scenario
from sil.analysis.metrics import load_trace, tracking_rms_pct
from sil.run.runner import RunOptions, run


def _run(name: str, out: Path, seed: int | None = None) -> dict[str, np.ndarray]:
    s = scenario.load(name)
    summary = run(RunOptions(s, out, mode="inproc", plots=False, progress=False, seed=seed))
    assert summary["status"] == "completed" and summary["missed_ticks"] == 0
    return load_trace(out / "trace.csv")


def test_mrac_tracks_the_staircase_at_least_twice_as_well_as_the_pid(tmp_path):
    mrac = tracking_rms_pct(_run("thesis-5.4-staircase", tmp_path / "mrac"))
    pid = tracking_rms_pct(_run("thesis-6.2-staircase-pid", tmp_path / "pid"))
    assert pid >= 2.0 * mrac, (mrac, pid)


@pytest.mark.parametrize("seed", [None, 7])
def test_after_the_pump_failure_the_mrac_keeps_tracking_and_lambda_halves(tmp_path, seed):
    s = scenario.load("thesis-6.3-failure-mrac")
    (fault,) = s.faults
    assert (fault.target, fault.value, fault.time_s) == ("PUMP_EFFECTIVENESS", 0.5, 30.0)
    tr = _run(s.name, tmp_path, seed)
    t, lam = tr["time"], tr["Est_Lambda"]
    before = tracking_rms_pct(tr, 0.0, fault.time_s)
    last = tracking_rms_pct(tr, s.duration_s - 60.0)
    assert last <= 1.5 * before, (before, last)
    lam_before = lam[np.searchsorted(t, fault.time_s) - 1]
    assert abs(lam[-1] / lam_before - 0.5) <= 0.15 * 0.5, (lam_before, lam[-1])
    # settled: the median over the last 20 s too (it dips for a second at steps down, where
    # the pump voltage falls at its slew limit)
    tail = lam[(t >= s.duration_s - 20.0) & np.isfinite(lam)]
    assert tail.size > 100 and abs(np.median(tail) / lam_before - 0.5) <= 0.15 * 0.5
    # the health alarm (below 70 % of the commissioned value) is raised and stays
    assert tr["PumpHealth"][-1] < 70.0
