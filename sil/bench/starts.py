"""`sil bench starts`: the start/stop sequencer's figures on the aero-thermal plant: the start
scenarios (sil/scenario/library/start-*.toml) run as ``sil run --mode inproc --ecu-impl c`` with
their summaries' start figures; the same starts in lockstep over the loopback bus and in real time
(keys ending in ``_lockstep``, ``_realtime``, beside the in-process ones; quick: each cut past its
start, so without the cool-down; the real-time runs all at once); and the start campaign
(sil/campaign/library/starts.toml; quick: its first 20 engines) as ``sil campaign --ecu-impl c``
with the spread of its start times.

Targets: the nominal start to idle (RUN) within 25 s with its EGT under the ECU's start limit;
the start with a failed igniter aborted with IGNITION_TIMEOUT within 30 s of the arming and the
engine under 373 K at the end; the nominal engine's EGT under 373 K for good within 60 s of the
fuel cut; every engine of the campaign at idle, with no hot start, hung start or overspeed;
every start alike in lockstep and in real time: the same abort, the start time within 1 s and
the EGT peak within 30 K of the in-process start's."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from ecu.params import EcuParams
from sil.bench.common import BenchError, completed_run
from sil.campaign import report
from sil.run.run_record import scenario_text
from sil.scenario import load

SCENARIOS = ("start-nominal", "start-cold-day", "start-hot-day", "start-no-light",
             "start-flameout-relight")  # fmt: skip
FIGURES = ("start_time_s", "start_egt_peak_K", "start_abort", "start_abort_s", "relights",
           "unburnt_fuel_kg", "cool_down_s", "final_egt_K")  # fmt: skip
CAMPAIGN = Path(__file__).resolve().parents[1] / "campaign" / "library" / "starts.toml"
QUICK_ENGINES = 20
MODES = ("lockstep", "realtime")  # beside the in-process figures
COMPARED = ("start_time_s", "start_egt_peak_K", "start_abort", "start_abort_s", "cool_down_s")
QUICK_CUT_S = {  # quick: each start scenario cut to this, past its start, relight or abort
    "start-nominal": 24.0,
    "start-cold-day": 24.0,
    "start-hot-day": 24.0,
    "start-no-light": 22.0,
    "start-flameout-relight": 36.0,
}
SAME_START_S = 1.0  # every mode: the start time within this of the in-process start's
SAME_EGT_K = 30.0  # ... and the EGT peak within this


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


def _scenario_file(name: str, folder: Path, quick: bool) -> Path:
    """The start scenario's file: the shipped one, or (quick) a copy cut past its start."""
    s = load(name)
    assert s.path is not None
    if not quick:
        return s.path
    path = folder / f"{name}-{QUICK_CUT_S[name]:g}s.toml"
    path.write_text(scenario_text(replace(s, duration_s=QUICK_CUT_S[name], stop_s=None), s.seed))
    return path


def _start_realtime(paths: dict[str, Path], folder: Path) -> dict[str, subprocess.Popen]:
    """The start scenarios in real time, all at once (each takes its simulated time in wall
    time; they wait on their clocks, so the bench's other runs go on meanwhile)."""
    return {
        name: subprocess.Popen(
            [
                sys.executable,
                "-m",
                "sil.cli",
                "run",
                str(path),
                "--mode",
                "realtime",
                "--ecu-impl",
                "c",
                "--out",
                str(folder / "realtime" / name),
                "--no-plots",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        for name, path in paths.items()
    }


def _realtime_summaries(procs: dict[str, subprocess.Popen], folder: Path) -> dict[str, dict]:
    """The real-time runs' summaries, once they have ended; each must have completed."""
    summaries = {}
    for name, proc in procs.items():
        _, stderr = proc.communicate()
        try:
            summary = json.loads((folder / "realtime" / name / "summary.json").read_text())
        except (OSError, ValueError):
            summary = {"status": f"no summary (exit {proc.returncode}: {stderr.strip()[-200:]})"}
        if summary.get("status") != "completed":
            raise BenchError(f"sil run {name} --mode realtime: {summary.get('status')}, "
                             f"{summary.get('abort_reason')}")  # fmt: skip
        summaries[name] = summary
    return summaries


def _same_start(figures: dict) -> bool:
    """Every mode started every engine as in process (see SAME_START_S, SAME_EGT_K)."""
    return all(
        _alike(*((figures.get(f"{_key(name)}_{f}"), figures.get(f"{_key(name)}_{f}_{mode}"))
                 for f in ("start_abort", "start_time_s", "start_egt_peak_K")))
        for name in SCENARIOS
        for mode in MODES
    )  # fmt: skip


def _alike(abort: tuple, time_s: tuple, egt: tuple) -> bool:
    """One start as in process (each figure: in process, in the other mode)."""
    if abort[0] != abort[1] or (time_s[0] is None) != (time_s[1] is None):
        return False
    if time_s[0] is not None and abs(time_s[0] - time_s[1]) > SAME_START_S:
        return False
    return None not in egt and abs(egt[0] - egt[1]) <= SAME_EGT_K


def _key(name: str) -> str:
    return name.removeprefix("start-").replace("-", "_")


def run(quick: bool = False) -> dict:
    figures: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = {name: _scenario_file(name, folder, quick) for name in SCENARIOS}
        realtime = _start_realtime(paths, folder)
        try:  # the other runs while the real-time ones fly
            inproc = {
                name: completed_run(
                    load(name).path, folder / name, "--mode", "inproc", "--ecu-impl", "c"
                )
                for name in SCENARIOS
            }
            lockstep = {
                name: completed_run(path, folder / "lockstep" / name, "--ecu-impl", "c")
                for name, path in paths.items()
            }
            campaign = _campaign(folder, quick)
        except BaseException:
            for proc in realtime.values():
                proc.kill()
                proc.wait()
            raise
        modes = {"lockstep": lockstep, "realtime": _realtime_summaries(realtime, folder)}
    for name in SCENARIOS:
        key = _key(name)
        for field in FIGURES:
            if inproc[name].get(field) is not None:
                figures[f"{key}_{field}"] = inproc[name][field]
            if field in COMPARED:  # side by side: the same figure in the other modes
                for mode in MODES:
                    if (value := modes[mode][name].get(field)) is not None:
                        figures[f"{key}_{field}_{mode}"] = value
    figures.update(campaign)
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
        "lockstep and real time start as in process (time 1 s, EGT 30 K, abort)": _same_start(
            figures
        ),
        "campaign: every engine at idle, no hot, hung start or overspeed": (
            figures["campaign_reached_idle"] == figures["campaign_engines"]
            and figures["campaign_hot_starts"] == 0
            and figures["campaign_hung_starts"] == 0
            and figures["campaign_overspeeds"] == 0
        ),
    }
    return figures
