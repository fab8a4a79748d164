"""`sil bench fleet`: the three controllers (the MRAC, the document's PID, the gain-scheduled PI)
across the engine variation, on the aero-thermal plant with the firmware's limit loops and fuel
schedules: the campaigns sil/campaign/library/engine-variation.toml (the staircase) and
transients.toml (idle to maximum and the throttle chop) as ``sil campaign --ecu-impl c`` (quick:
their first 20 engines), the sec. 6.3 pump failure flown by each controller, and the fastest rise
the fuel schedule's physics allows (plant.schedules, frozen speed, lags neglected).

Targets: no run of the engine variation breaks an invariant; in the transients the EGT at most
10 K over its limit, no surge, no flameout and no undershoot; idle to 95 % of the thrust within
5 s for every engine (14 CFR 33.73); the MRAC tracking closer than both baselines, across the
engine variation (median) and in the pump failure."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

from plant import schedules
from plant.aerothermal import make_model
from plant.steady_line import running_line
from sil.bench.common import BenchError, completed_run
from sil.campaign import report
from sil.campaign.tomlw import dumps
from sil.scenario import load

CAMPAIGNS = Path(__file__).resolve().parents[1] / "campaign" / "library"
QUICK_ENGINES = 20
CONTROLLERS = ("mrac", "pid", "pi")
# the sec. 6.3 pump failure, each controller's scenario (the PI's: the MRAC's, kind "pi")
FAILURE = {"mrac": "thesis-6.3-failure-mrac", "pid": "thesis-6.3-failure-pid",
           "pi": "thesis-6.3-failure-mrac"}  # fmt: skip
RISE_S = 5.0  # 14 CFR 33.73: idle to 95 % of the thrust

TARGET_TEXT = {
    "variation": "engine variation: no run breaks an invariant",
    "transient_limits": "transients: EGT <= 10 K over its limit, no surge, flameout or undershoot",
    "rise": "transients: idle to 95 % thrust within 5 s, every engine",
    "mrac_tracks_closer": "MRAC tracks closer than the PI and the PID (variation median)",
    "mrac_failure": "sec. 6.3 pump failure: MRAC tracks closer than the PI and the PID",
}


def _rounded(value: float | None, digits: int) -> float | None:
    """``round``, where a figure the campaign could not measure (None, NaN) stays None."""
    if value is None or value != value:
        return None
    return round(value, digits)


def _campaign(name: str, base: str, folder: Path, quick: bool) -> list[dict]:
    """``sil campaign NAME.toml --ecu-impl c`` (quick: its first QUICK_ENGINES engines); the
    rows of its results."""
    text = (CAMPAIGNS / f"{name}.toml").read_text()
    if quick:
        text = re.sub(r"(?m)^samples = .*$", f"samples = {QUICK_ENGINES - 1}", text)
    text = re.sub(r"(?m)^base = .*$", f'base = "{load(base).path}"', text)
    spec = folder / f"{name}.toml"
    spec.write_text(text)
    out = folder / name
    cmd = [sys.executable, "-m", "sil.cli", "campaign", str(spec), "--ecu-impl", "c",
           "--out", str(out), "--no-progress", "--no-report"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    try:
        return report.load(out / "results.csv")
    except OSError:
        tail = proc.stderr.strip()[-300:]
        raise BenchError(f"sil campaign {name}: no results ({tail})") from None


def _kinds(rows: list[dict]) -> list[str]:
    """Every violation's kind (the text before its colon), one per violation."""
    return [v.split(":")[0] for r in rows if r["violations"] for v in r["violations"].split("; ")]


def _variation(rows: list[dict]) -> dict:
    out: dict = {
        "variation_runs": len(rows),
        "variation_runs_with_violations": sum(1 for r in rows if r["violations"]),
        "variation_failed_runs": sum(1 for r in rows if r["status"] != "completed"),
    }
    for name, t in report.tracking(rows).items():
        out[f"variation_{name}_rms_nominal_pct"] = _rounded(t["nominal"], 4)
        out[f"variation_{name}_rms_median_pct"] = _rounded(t["p50"], 4)
        out[f"variation_{name}_rms_p95_pct"] = _rounded(t["p95"], 4)
        out[f"variation_{name}_held_engines"] = t["limited"]
        out[f"variation_{name}_rms_p95_free_pct"] = _rounded(t["p95_free"], 4)
        out[f"variation_{name}_limiter_time_nominal_s"] = _rounded(t["limiter_s_nominal"], 2)
        out[f"variation_{name}_limiter_time_median_s"] = _rounded(t["limiter_s_p50"], 2)
        out[f"variation_{name}_limiter_time_mean_s"] = _rounded(t["limiter_s_mean"], 2)
    return out


def _transients(rows: list[dict]) -> dict:
    out: dict = {
        "transient_runs": len(rows),
        "transient_failed_runs": sum(1 for r in rows if r["status"] != "completed"),
    }
    for s in report.transients(rows):
        key = f"transient_{s['controller']}_{s['variant']}"
        if s["step_pct"] > 0.0:  # the step up: the thrust's rise
            for q in ("nominal", "p50", "p95", "max"):
                out[f"{key}_rise_{q.replace('p50', 'median')}_s"] = _rounded(s[f"rise_{q}"], 2)
            rise = np.array([
                float(r["thrust_rise_s"] or "nan") for r in rows
                if r["controller.kind"] == s["controller"] and r["variant"] == s["variant"]
            ])  # fmt: skip
            out[f"{key}_within_5_s"] = int(np.sum(rise <= RISE_S))
            out[f"{key}_engines"] = int(rise.size)
        else:  # the chop: the thrust's fall
            out[f"{key}_fall_nominal_s"] = _rounded(s["rise_nominal"], 2)
            out[f"{key}_fall_median_s"] = _rounded(s["rise_p50"], 2)
        out[f"{key}_egt_overshoot_max_K"] = _rounded(s["egt_overshoot_max"], 1)
        out[f"{key}_surge_margin_min_pct"] = _rounded(s["surge_margin_min"], 1)
        out[f"{key}_flameout_runs"] = s["flameout_runs"]
        out[f"{key}_speed_min_pct"] = _rounded(s["speed_min"], 1)
    kinds = _kinds(rows)
    out["transient_limit_violations"] = sum(k != "thrust_rise" for k in kinds)
    out["transient_rise_violations"] = kinds.count("thrust_rise")
    return out


def _failure(folder: Path) -> dict:
    """The sec. 6.3 pump failure flown by each controller: its tracking RMS."""
    out = {}
    for kind in CONTROLLERS:
        data = tomllib.loads(load(FAILURE[kind]).path.read_text())
        data["controller"]["kind"] = kind
        path = folder / f"failure-{kind}.toml"
        path.write_text(dumps(data))
        summary = completed_run(path, folder / f"failure-{kind}", "--mode", "inproc", "--ecu-impl",
                                "c")  # fmt: skip
        out[f"failure_{kind}_tracking_rms_pct"] = _rounded(summary["tracking_rms_pct"], 4)
    return out


def _rise_bounds(quick: bool) -> dict:
    """The fastest rise from idle the schedules' physics allows (frozen speed, lags neglected):
    the nominal engine on its own acceleration line and (full) on the fleet's, the ECU's; and
    how many health corners cannot rise within RISE_S even on their own line."""
    model = make_model()
    line = running_line(model)
    own = schedules.schedule(model)
    out = {"rise_bound_nominal_own_line_s": _rounded(schedules.line_rise_s(own, line), 2)}
    if quick:
        return out
    corners = schedules.corner_schedules(model)
    fleet = schedules.fleet_schedule(model, corners=corners)
    out["rise_bound_nominal_fleet_line_s"] = _rounded(schedules.line_rise_s(fleet, line), 2)
    slow = [
        len(pts) < 2 or not schedules.line_rise_s(pts, corner_line) <= RISE_S
        for corner_line, pts in corners
    ]
    out["health_corners"] = len(corners)
    out["health_corners_over_5_s_on_own_line"] = sum(slow)
    return out


def run(quick: bool = False) -> dict:
    figures: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        variation = _campaign("engine-variation", "thesis-5.4-staircase", folder, quick)
        transients = _campaign("transients", "accel-idle-to-max", folder, quick)
        figures.update(_variation(variation))
        figures.update(_transients(transients))
        figures.update(_failure(folder))
    figures.update(_rise_bounds(quick))
    rises = [figures[f"transient_{k}_accel_within_5_s"] for k in CONTROLLERS]
    engines = [figures[f"transient_{k}_accel_engines"] for k in CONTROLLERS]
    rms = {k: figures[f"variation_{k}_rms_median_pct"] for k in CONTROLLERS}
    failure = {k: figures[f"failure_{k}_tracking_rms_pct"] for k in CONTROLLERS}
    figures["targets_met"] = {
        "variation": figures["variation_runs_with_violations"] == 0
        and figures["variation_failed_runs"] == 0,
        "transient_limits": figures["transient_limit_violations"] == 0
        and figures["transient_failed_runs"] == 0,
        "rise": all(r == e for r, e in zip(rises, engines, strict=True)),
        "mrac_tracks_closer": rms["mrac"] < min(rms["pi"], rms["pid"]),
        "mrac_failure": failure["mrac"] < min(failure["pi"], failure["pid"]),
    }
    if not all(math.isfinite(v) for v in rms.values()):
        raise BenchError(f"a controller's engine variation has no tracking figure: {rms}")
    return figures
