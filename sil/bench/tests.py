"""`sil bench tests`: how long the test suite takes, tier by tier, as a developer runs it from the
checkout: ``python3 dev.py test --quick`` (the fast tier) and, unless quick, ``python3 dev.py
test`` (the whole suite: its part on every core, the vcan VM among it, then its part paced by the
wall clock, alone). Each tier runs once, in a process of its own, after the environment is set
up (the install step is not timed); the figures are its wall time, each part's time as pytest
gives it, and the tests passed and failed.

Targets: the fast tier under 3 minutes, the whole suite at most 20 minutes on 2 cores, with no
test failed."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from sil.bench.common import BenchError

ROOT = Path(__file__).resolve().parents[2]
DEV = ROOT / "dev.py"
TIERS = {"quick": ("--quick",), "full": ()}
LIMITS_S = {"quick": 180.0, "full": 1200.0}
TARGET_TEXT = {
    "quick_under_3_min": "the fast tier (`python3 dev.py test --quick`) under 3 minutes",
    "full_within_20_min": "the whole suite (`python3 dev.py test`) within 20 minutes",
}
# pytest's last line of a part: "==== 1567 passed, 71 deselected in 612.34s (0:10:12) ===="
PART_END = re.compile(r"^=+ (?P<counts>.*) in (?P<seconds>[\d.]+)s(?: \([\d:]+\))? =+$", re.M)
COUNT = re.compile(r"(\d+) (passed|failed|errors?|skipped|deselected|xfailed|xpassed)")


def _setup() -> None:
    """``python3 dev.py setup``: the environment current before anything is timed."""
    if not DEV.is_file() or not (ROOT / "tests").is_dir():
        raise BenchError(
            f"no test suite beside {ROOT / 'sil'}: `sil bench tests` runs in a checkout "
            "(dev.py and tests/)"
        )
    done = subprocess.run([sys.executable, str(DEV), "setup"], cwd=ROOT, capture_output=True)
    if done.returncode != 0:
        raise BenchError(f"python3 dev.py setup failed (exit {done.returncode})")


def parts(output: str) -> list[dict]:
    """Each part's counts and seconds from pytest's output (one line per part that ran)."""
    found = []
    for end in PART_END.finditer(output):
        counts = {kind.rstrip("s") if kind.startswith("error") else kind: int(n)
                  for n, kind in COUNT.findall(end["counts"])}  # fmt: skip
        found.append({"seconds": float(end["seconds"]), **counts})
    return found


def _tier(name: str) -> dict:
    print(f"sil bench tests: python3 dev.py test {' '.join(TIERS[name])}".rstrip(), file=sys.stderr)
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, str(DEV), "test", *TIERS[name]], cwd=ROOT, capture_output=True, text=True
    )
    wall = time.perf_counter() - started
    found = parts(done.stdout)
    if not found:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise BenchError(f"python3 dev.py test {name}: no pytest summary (exit "
                         f"{done.returncode}): {tail}")  # fmt: skip
    figures = {
        f"{name}_s": round(wall, 1),
        f"{name}_parts_s": [p["seconds"] for p in found],
        f"{name}_passed": sum(p.get("passed", 0) for p in found),
        f"{name}_failed": sum(p.get("failed", 0) + p.get("error", 0) for p in found),
    }
    print(f"  {figures[f'{name}_s']} s, {figures[f'{name}_passed']} passed, "
          f"{figures[f'{name}_failed']} failed", file=sys.stderr)  # fmt: skip
    return figures


def run(quick: bool = False) -> dict:
    _setup()
    figures: dict = {
        "cores": os.cpu_count(),
        "load_average_1min_before": round(os.getloadavg()[0], 2),
    }
    met = {}
    for name, key in (("quick", "quick_under_3_min"), ("full", "full_within_20_min")):
        if quick and name == "full":
            continue
        figures |= _tier(name)
        met[key] = figures[f"{name}_s"] <= LIMITS_S[name] and figures[f"{name}_failed"] == 0
    figures["targets_met"] = met
    return figures
