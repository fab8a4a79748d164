"""`sil bench starts`: the start/stop sequencer's figures on the aero-thermal plant: the start
scenarios (sil/scenarios/start-*.toml) run as ``sil run --mode inproc --ecu-impl c`` with their
summaries' start figures, and the start campaign (sil/campaigns/starts.toml; quick: its first 20
engines) as ``sil campaign --ecu-impl c`` with the spread of its start times.

Targets: the nominal start to idle (RUN) within 25 s with its EGT under the ECU's start limit;
the start with a failed igniter aborted with IGNITION_TIMEOUT within 30 s of the arming and the
engine under 373 K at the end; the nominal engine's EGT under 373 K for good within 60 s of the
fuel cut; every engine of the campaign at idle, with no hot start, hung start or overspeed."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from ecu.params import EcuParams
from sil.bench import BenchError, completed_run
from sil.campaign import report
from sil.scenario import load

SCENARIOS = ("start-nominal", "start-cold-day", "start-hot-day", "start-no-light",
             "start-flameout-relight")  # fmt: skip
FIGURES = ("start_time_s", "start_egt_peak_K", "start_abort", "start_abort_s", "relights",
           "unburnt_fuel_kg", "cool_down_s", "final_egt_K")  # fmt: skip
CAMPAIGN = Path(__file__).resolve().parent / "campaigns" / "starts.toml"
QUICK_ENGINES = 20


def _campaign(folder: Path, quick: bool) -> dict:
    """The start campaign (quick: QUICK_ENGINES engines) and its start figures."""
    text = CAMPAIGN.read_text()
    if quick:
        text = re.sub(r"(?m)^samples = .*$", f"samples = {QUICK_ENGINES - 1}", text)
    base = load("start-nominal").path
    text = re.sub(r"(?m)^base = .*$", f'base = "{base}"', text)
    spec = folder / "starts.toml"
    spec.write_text(text)
    out = folder / "campaign"
    cmd = [sys.executable, "-m", "sil.cli", "campaign", str(spec), "--ecu-impl", "c",
           "--out", str(out), "--no-progress", "--no-report"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    try:
        rows = report.load(out / "results.csv")
    except OSError:
        tail = proc.stderr.strip()[-300:]
        raise BenchError(f"sil campaign starts: no results ({tail})") from None
    spread = report.starts(rows) or {"reached": 0, "time": (math.nan,) * 3,
                                     "egt": (math.nan,) * 3, "cool": (math.nan,) * 2}  # fmt: skip
    violations = [r["violations"] for r in rows if r["violations"]]
    kinds = [v.split(":")[0] for vs in violations for v in vs.split("; ")]
    return {
        "campaign_engines": len(rows),
        "campaign_reached_idle": spread["reached"],
        "campaign_start_time_median_s": spread["time"][0],
        "campaign_start_time_p95_s": spread["time"][1],
        "campaign_start_time_max_s": spread["time"][2],
        "campaign_start_egt_peak_max_K": spread["egt"][2],
        "campaign_cool_down_max_s": spread["cool"][1],
        "campaign_hot_starts": kinds.count("hot_start"),
        "campaign_hung_starts": kinds.count("hung_start"),
        "campaign_overspeeds": kinds.count("overspeed"),
        "campaign_runs_with_violations": len(violations),
    }


def run(quick: bool = False) -> dict:
    figures: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in SCENARIOS:
            path = load(name).path
            summary = completed_run(path, folder / name, "--mode", "inproc", "--ecu-impl", "c")
            key = name.removeprefix("start-").replace("-", "_")
            for field in FIGURES:
                if summary.get(field) is not None:
                    figures[f"{key}_{field}"] = summary[field]
        figures.update(_campaign(folder, quick))
    limit = EcuParams().start_egt_limit_k
    figures["targets_met"] = {
        "nominal start to idle within 25 s": figures.get("nominal_start_time_s", math.inf) <= 25.0,
        "nominal start's EGT under the start limit": figures["nominal_start_egt_peak_K"] < limit,
        "no light: IGNITION_TIMEOUT within 30 s, cooled": (
            figures.get("no_light_start_abort") == "IGNITION_TIMEOUT"
            and figures.get("no_light_start_abort_s", math.inf) <= 30.0
            and figures.get("no_light_final_egt_K", math.inf) < 373.0
        ),
        "nominal cool-down under 373 K within 60 s": (
            figures.get("nominal_cool_down_s", math.inf) <= 60.0
        ),
        "campaign: every engine at idle, no hot, hung start or overspeed": (
            figures["campaign_reached_idle"] == figures["campaign_engines"]
            and figures["campaign_hot_starts"] == 0
            and figures["campaign_hung_starts"] == 0
            and figures["campaign_overspeeds"] == 0
        ),
    }
    return figures
