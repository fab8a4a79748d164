"""A run's results folder (``sil run --out``): the names a run writes, and its summary's status.

A run owns only the names in :data:`RUN_FILES`: before it starts, those left by an earlier run
in the folder are removed (a user's own files stay), and ``summary.json`` says at once that the
run is ``running``. It is replaced, atomically, by the final summary (``completed`` or
``aborted``), or by a ``failed`` one naming the reason when the run fails before it began or
while it ended. A run killed outright leaves ``running``. ``status`` is always the first key.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from protocol import strict_json

SUMMARY = "summary.json"
COMPLETED = "completed"
PLOTS = ("speed.png", "egt.png", "estimates.png", "gains.png")  # sil.plots.plot_run
RUN_FILES = (
    SUMMARY,
    "can.log",
    "can.asc",
    "can.blf",
    "trace.csv",
    "scenario.toml",
    *("run.json", "commissioning.json"),  # what shaped the run (sil.run_record)
    "plant.log",
    "ecu.log",
    *PLOTS,
    "compare.png",  # `sil compare`'s plot goes into the second run's folder by default
    # the node processes' handshake and stats files (sil.runner), the summary being written
    ".plant-ready",
    ".ecu-ready",
    ".plant-start",
    ".plant-stats.json",
    ".ecu-stats.json",
    f".{SUMMARY}.tmp",
)


def clear(out_dir: Path) -> list[str]:
    """Remove what an earlier run left in ``out_dir`` (only :data:`RUN_FILES`); the names
    removed, in order."""
    removed = []
    for name in RUN_FILES:
        path = out_dir / name
        if path.is_file() or path.is_symlink():
            path.unlink()
            removed.append(name)
    return removed


def status_first(summary: dict) -> dict:
    """The summary with ``status`` as its first key."""
    return {"status": summary["status"], **summary}


def write_summary(out_dir: Path, summary: dict) -> Path:
    """Write ``summary.json`` (status first) atomically: a reader sees the old or the new one."""
    path = out_dir / SUMMARY
    tmp = out_dir / f".{SUMMARY}.tmp"
    tmp.write_text(strict_json.dumps(status_first(summary), indent=2, default=float) + "\n")
    os.replace(tmp, path)
    return path


def mark(out_dir: Path, status: str, scenario: str, reason: str | None = None) -> Path:
    """A summary with only the status (``running``, ``failed``), the reason and the scenario."""
    return write_summary(out_dir, {"status": status, "abort_reason": reason, "scenario": scenario})


class IncompleteRun(ValueError):
    """A folder that does not hold a completed run; the message names the folder and why."""


def load_summary(out_dir: Path) -> dict:
    """The run's summary; :class:`IncompleteRun` when it is missing or unreadable."""
    if not out_dir.is_dir():
        raise IncompleteRun(f"{out_dir}: no such folder")
    path = out_dir / SUMMARY
    if not path.is_file():
        raise IncompleteRun(f"{out_dir}: no {SUMMARY} (is this the output folder of a run?)")
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise IncompleteRun(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("status"), str):
        raise IncompleteRun(f"{path}: no 'status' field: not a run's summary")
    return summary


def incomplete_reason(summary: dict) -> str | None:
    """Why a run's results are not those of a completed run (None if they are)."""
    status = summary["status"]
    if status == COMPLETED:
        return None
    if status == "running":
        return "status running: the run is still going or was killed before it ended"
    reason = summary.get("abort_reason")
    return f"status {status}" + (f": {reason}" if reason else "")
