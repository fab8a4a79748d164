"""Transient invariants of a campaign (thrust rise, surge, flameout, undershoot) on the plant's
truth, against the same figures of `sil run` from the recorded trace."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from sil.cli import main

TRANSIENTS = """
name = "t"
base = "accel-idle-to-max"
duration_s = 6

[sweep]
"controller.kind" = ["pi"]

[[variant]]
name = "accel"

[[variant]]
name = "chop"
plant = { initial_speed_pct = 100 }
command = { base = 100, component = [{ kind = "step", time_s = 1, value = -45 }] }

[[variant]]
name = "fuel-cut"   # the pump stops delivering at 2 s: the burner goes out in RUN
[[variant.fault]]
time_s = 2
target = "PUMP_EFFECTIVENESS"
value = 0.0
"""


def _rows(out: Path) -> dict[str, dict]:
    with (out / "results.csv").open(newline="") as f:
        return {r["variant"]: r for r in csv.DictReader(f)}


def test_transient_invariants_and_figures(write, tmp_path):
    text = TRANSIENTS + "\n[invariants]\nmax_thrust_rise_s = 1.0\ncheck_undershoot = true\n"
    out = tmp_path / "out"
    assert main(["campaign", str(write(text)), "--out", str(out), "--no-progress"]) == 1
    rows = _rows(out)
    accel, chop, cut = rows["accel"], rows["chop"], rows["fuel-cut"]
    assert float(accel["step_pct"]) == 45.0 and float(chop["step_pct"]) == -45.0
    # the rise is checked on the step up only
    assert "thrust_rise:" in accel["violations"] and "thrust_rise" not in chop["violations"]
    assert float(accel["thrust_rise_s"]) > 1.0 and float(chop["thrust_rise_s"]) > 0.0
    assert int(accel["flameouts"]) == int(chop["flameouts"]) == 0
    assert int(cut["flameouts"]) == 1 and "flameout: 1 while in RUN" in cut["violations"]
    assert "undershoot" not in accel["violations"]
    for r in rows.values():
        assert 0.0 < float(r["min_surge_margin_pct"]) < 100.0
    report = (out / "report.md").read_text()
    row = next(ln for ln in report.splitlines() if ln.startswith("| pi | accel | +45 | 1 |"))
    assert f"{float(accel['thrust_rise_s']):.2f} / {float(accel['thrust_rise_s']):.2f}" in row
    assert "target (within 2x)" not in report  # the staircase's targets are not judged here
    # the same figures from `sil run` of the case (the trace: CAN resolution, sensor EGT)
    run = tmp_path / "run"
    scenario = out / "scenarios" / f"{accel['run_id']}.toml"
    assert main(["run", str(scenario), "--mode", "inproc", "--out", str(run), "--no-plots"]) == 0
    summary = json.loads((run / "summary.json").read_text())
    assert summary["thrust_rise_s"] == pytest.approx(float(accel["thrust_rise_s"]), abs=0.02)
    assert summary["min_surge_margin_pct"] == pytest.approx(
        float(accel["min_surge_margin_pct"]), abs=0.05
    )


def test_a_surge_margin_floor_is_an_invariant(write, tmp_path):
    text = TRANSIENTS.replace('[[variant]]\nname = "chop"', '[[variant]]\nname = "chop"', 1)
    text += "\n[invariants]\nmin_surge_margin_pct = 60.0\ncheck_flameout = false\n"
    out = tmp_path / "out"
    assert main(["campaign", str(write(text)), "--out", str(out), "--no-progress"]) == 1
    for r in _rows(out).values():
        assert r["violations"].startswith("surge: margin ")
        assert "flameout" not in r["violations"]
