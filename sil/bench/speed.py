"""`sil bench sil`: real-time factor of a whole SIL run, in lockstep over the bus and in process,
with the Python firmware and with its C port as the ECU (keys of the C runs end in ``_c_ecu``);
in process with the C ECU the compiled loop (sil/run/compiled_loop.py) and, for the ratio in the
same minutes, the Python loop it replaces (``_c_ecu_python_loop``).

Each run is the ``sil run`` command in a process of its own, as a user runs it (its set-up cold,
as it is then: the node processes start while it is done, see :mod:`sil.run.runner`), and its
figures are the ones it writes in summary.json. Each of the four runs is repeated (alternated, so
that a busy spell of a shared machine hits all alike) and the best is reported, with every run's
figure under ``..._runs``. The machine's pace before and after (``..._before``, ``..._after``): the
Python firmware's tick and the plant's ECU period, each in a loop of its own, which the
real-time factors scale with (a shared machine's pace drifts by a third from minute to minute)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from sil import scenario
from sil.bench.common import BenchError, scenario_cut

SCENARIO = "thesis-5.3-mrac-aero"  # 300 s, aero-thermal plant, 1 ms steps, ECU at 100 Hz
MODES = (("lockstep", "realtime_factor"), ("inproc", "inproc_realtime_factor"))
# (`--ecu-impl`, more `sil run` arguments, suffix of its keys, modes)
CASES = (
    ("python", (), "", MODES),
    ("c", (), "_c_ecu", MODES),
    ("c", ("--python-loop",), "_c_ecu_python_loop", MODES[1:]),
)
TARGETS = {  # key: the least real-time factor the bench accepts (TARGET_TEXT says each)
    "realtime_factor": 40.0,
    "inproc_realtime_factor": 100.0,
    "inproc_realtime_factor_c_ecu": 500.0,
}
TARGET_TEXT = {
    "realtime_factor": ">= 40x real time, lockstep over the loopback bus",
    "inproc_realtime_factor": ">= 100x real time in process, Python ECU",
    "inproc_realtime_factor_c_ecu": ">= 500x real time in process, C ECU",
}
REPEATS = 3  # (1 with --quick)
QUICK_S = 30.0  # --quick: the scenario cut to this


def _scenario_file(s: scenario.Scenario, tmp: Path, quick: bool) -> str:
    """The scenario to run: the shipped one, or (quick) a copy of its file cut to QUICK_S."""
    return str(scenario_cut(s.name, QUICK_S, tmp)) if quick else s.name


def _sil_run(name: str, out: Path, mode: str, impl: str, extra: tuple[str, ...] = ()) -> dict:
    """``sil run`` in a process of its own; its summary."""
    cmd = [sys.executable, "-m", "sil.cli", "run", name, "--out", str(out), "--mode", mode]
    cmd += ["--ecu-impl", impl, "--no-plots", *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    try:
        return json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        args = " ".join((name, "--mode", mode, "--ecu-impl", impl, *extra))
        raise BenchError(
            f"sil run {args} exited with code {proc.returncode} and no summary: {' / '.join(tail)}"
        ) from None


def _pace(s: scenario.Scenario, when: str) -> dict:
    """The firmware's tick and the plant's ECU period now, each alone (a second in all)."""
    from ecu import bench as ecu_bench
    from sil.bench.port import plant_bound

    tick = ecu_bench.run(quick=True)["us_per_tick"]
    plant = plant_bound(s)["plant_cpu_us_per_ecu_tick"]
    return {f"python_tick_us_{when}": tick, f"plant_us_per_ecu_tick_{when}": plant}


def run(quick: bool = False) -> dict:
    s = scenario.load(SCENARIO)
    figures: dict = {"scenario": s.name, "sim_time_s": QUICK_S if quick else s.duration_s}
    figures["load_average_1min_before"] = round(os.getloadavg()[0], 2)  # others' load, mostly
    figures.update(_pace(s, "before"))
    runs: dict[str, list[float]] = {}
    repeats = 1 if quick else REPEATS
    total = repeats * sum(len(modes) for *_, modes in CASES)
    with tempfile.TemporaryDirectory() as tmp:
        name = _scenario_file(s, Path(tmp), quick)
        for _ in range(repeats):
            for impl, extra, suffix, modes in CASES:
                for mode, key in modes:
                    out = Path(tmp) / f"{mode}{suffix}"
                    summary = _sil_run(name, out, mode, impl, extra)
                    factor = round(summary["realtime_factor"], 2)
                    runs.setdefault(key + suffix, []).append(factor)
                    done = sum(map(len, runs.values()))
                    what = f"{mode}, {impl} ECU{' ' if extra else ''}{' '.join(extra)}"
                    print(f"run {done}/{total}: {what}: {factor}x", file=sys.stderr)
                    if factor < max(runs[key + suffix]):
                        continue  # the figures below are the best run's
                    figures[key + suffix] = factor
                    figures[f"{mode}_wall_s{suffix}"] = round(summary["wall_time_s"], 2)
                    figures[f"{mode}_missed_ticks{suffix}"] = summary["missed_ticks"]
                    figures.pop(f"{mode}_aborted{suffix}", None)
                    if summary["status"] != "completed":
                        figures[f"{mode}_aborted{suffix}"] = summary["abort_reason"]
                    if "startup_s" in summary:  # lockstep without the node processes' start
                        loop_s = summary["wall_time_s"] - summary["startup_s"]
                        figures[f"lockstep_startup_s{suffix}"] = round(summary["startup_s"], 2)
                        figures[f"lockstep_loop_realtime_factor{suffix}"] = round(
                            summary["sim_time_s"] / loop_s, 2
                        )
                    if mode == "lockstep" and not suffix:
                        figures["bus"] = summary["bus"]
                        figures["bus_load_pct"] = round(summary["bus_load_pct"], 2)
    figures.update(_pace(s, "after"))
    for key, factors in runs.items():
        figures[f"{key}_runs"] = factors
    compiled, python = (
        runs["inproc_realtime_factor_c_ecu"],
        runs["inproc_realtime_factor_c_ecu_python_loop"],
    )  # in process with the C ECU, the compiled loop against the Python one, run by run
    figures["inproc_c_ecu_compiled_over_python_loop"] = round(
        sum(a / b for a, b in zip(compiled, python, strict=True)) / len(compiled), 2
    )
    figures["targets_met"] = {key: figures[key] >= at for key, at in TARGETS.items()}
    return figures
