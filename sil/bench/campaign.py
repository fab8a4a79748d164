"""`sil bench campaign`: how many runs a minute ``sil campaign --ecu-impl c`` flies with two
workers, on the local process pool and on a local Dask cluster: the shipped campaign
sil/campaign/library/bus-faults.toml (quick: one seed instead of five, 28 runs), each flown as
the user flies it, in a process of its own (start-up of the workers included), the executors
alternated (twice each; quick: once), the best of each kept; and whether both executors gave
the same results.

Target: >= 1,000 runs a minute with the C ECU, local pool and Dask."""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from sil.bench.common import BenchError
from sil.scenario import load

CAMPAIGN = Path(__file__).resolve().parents[1] / "campaign" / "library" / "bus-faults.toml"
WORKERS = 2
EXECUTORS = ("local", "dask")
REPEATS = 2  # (1 with --quick)
TARGETS = {f"runs_per_min_{executor}": 1000.0 for executor in EXECUTORS}
TARGET_TEXT = {
    "runs_per_min_local": ">= 1,000 runs a minute with the C ECU, local pool (2 workers)",
    "runs_per_min_dask": ">= 1,000 runs a minute with the C ECU, Dask (a local cluster of 2)",
}
UNTIMED = ("wall_s",)  # the columns that may differ between two flights of the same runs


def _campaign_file(folder: Path, quick: bool) -> Path:
    """A copy of the campaign naming its base scenario's file (quick: seed 1 only)."""
    text = CAMPAIGN.read_text()
    base = re.search(r'(?m)^base = "(.*)"$', text)
    if base is None:
        raise BenchError(f"{CAMPAIGN}: no 'base = \"...\"' line")
    text = text.replace(base[0], f'base = "{load(base[1]).path}"')
    if quick:
        text, cut = re.subn(r"(?m)^seed = \[.*\]$", "seed = [1]", text)
        if cut != 1:
            raise BenchError(f"{CAMPAIGN}: no single 'seed = [...]' sweep line to cut")
    path = folder / CAMPAIGN.name
    path.write_text(text)
    return path


def _fly(spec: Path, out: Path, executor: str) -> dict:
    """``sil campaign SPEC --ecu-impl c --executor EXECUTOR`` in a process of its own; its
    outcome, which must have every run completed."""
    cmd = [sys.executable, "-m", "sil.cli", "campaign", str(spec), "--ecu-impl", "c",
           "--executor", executor, "--workers", str(WORKERS), "--out", str(out),
           "--no-report", "--no-progress", "--json"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    try:
        outcome = json.loads(proc.stdout)
    except ValueError:
        tail = proc.stderr.strip().splitlines()[-3:]
        raise BenchError(
            f"sil campaign --executor {executor} (exit {proc.returncode}): {tail}"
        ) from None
    if outcome["failed"] or not outcome["completed"]:
        raise BenchError(f"sil campaign --executor {executor}: {outcome['failed']} runs failed")
    return outcome


def _rows(out: Path) -> dict[str, dict]:
    """The results of a campaign by run ID, without the columns that are timings."""
    with (out / "results.csv").open(newline="") as f:
        return {
            r["run_id"]: {k: v for k, v in r.items() if k not in UNTIMED} for r in csv.DictReader(f)
        }


def run(quick: bool = False) -> dict:
    figures: dict = {"campaign": CAMPAIGN.stem, "ecu_impl": "c", "workers": WORKERS}
    figures["load_average_1min_before"] = round(os.getloadavg()[0], 2)  # others' load, mostly
    rates: dict[str, list[float]] = {executor: [] for executor in EXECUTORS}
    with tempfile.TemporaryDirectory() as tmp:
        spec = _campaign_file(Path(tmp), quick)
        for repeat in range(1 if quick else REPEATS):
            for executor in EXECUTORS:
                out = Path(tmp) / f"{executor}-{repeat}"
                outcome = _fly(spec, out, executor)
                rates[executor].append(round(outcome["runs_per_min"], 1))
                figures["runs"] = outcome["completed"]
                print(f"{executor}: {rates[executor][-1]} runs/min", file=sys.stderr)
        figures["same_results_local_and_dask"] = _rows(Path(tmp) / "local-0") == _rows(
            Path(tmp) / "dask-0"
        )
    for executor, runs in rates.items():
        figures[f"runs_per_min_{executor}"] = max(runs)
        figures[f"runs_per_min_{executor}_runs"] = runs
    figures["targets_met"] = {key: figures[key] >= at for key, at in TARGETS.items()}
    return figures
