"""`sil bench sil`: real-time factor of a whole SIL run, in lockstep over the bus and in process."""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

from sil import scenario
from sil.runner import RunOptions
from sil.runner import run as run_scenario

SCENARIO = "thesis-5.3-mrac-aero"  # 300 s, aero-thermal plant, 1 ms steps, ECU at 100 Hz


def run(quick: bool = False) -> dict:
    s = scenario.load(SCENARIO)
    if quick:
        s = dataclasses.replace(s, duration_s=30.0)
    figures: dict = {"scenario": s.name, "sim_time_s": s.duration_s}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("lockstep", "inproc"):
            summary = run_scenario(
                RunOptions(s, Path(tmp) / mode, mode=mode, plots=False, progress=False)
            )
            key = "realtime_factor" if mode == "lockstep" else "inproc_realtime_factor"
            figures[key] = round(summary["realtime_factor"], 2)
            figures[f"{mode}_wall_s"] = round(summary["wall_time_s"], 2)
            figures[f"{mode}_missed_ticks"] = summary["missed_ticks"]
            if mode == "lockstep":
                figures["bus"] = summary["bus"]
                figures["bus_load_pct"] = round(summary["bus_load_pct"], 2)
    return figures
