"""What the benches share: a shipped scenario cut to a duration, ``sil run`` in a process of its
own and its summary, and the error a bench ends with when a run gives none."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from sil import scenario


class BenchError(RuntimeError):
    """A run of the bench failed to produce its summary."""


def scenario_cut(name: str, seconds: float, folder: Path, head: str = "") -> Path:
    """A copy of the shipped scenario ``name`` in ``folder`` with its duration set to
    ``seconds`` (and ``head``, TOML lines, before its own)."""
    s = scenario.load(name)
    assert s.path is not None  # (a shipped scenario has its file)
    text, cut = re.subn(r"(?m)^duration_s = .*$", f"duration_s = {seconds:g}", s.path.read_text())
    if cut != 1:
        raise BenchError(f"{s.path}: no single 'duration_s = ...' line to set")
    path = folder / f"{s.name}-{seconds:g}s.toml"
    path.write_text(head + text)
    return path


def finished_run(path: Path, out: Path, *args: str) -> dict:
    """``sil run PATH ARGS`` in a process of its own; its summary, whatever its status."""
    cmd = [sys.executable, "-m", "sil.cli", "run", str(path), *args]
    proc = subprocess.run([*cmd, "--out", str(out), "--no-plots"], capture_output=True, text=True)
    try:
        return json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise BenchError(
            f"sil run {path.name} {' '.join(args)} (exit {proc.returncode}, no summary): {tail}"
        ) from None


def completed_run(path: Path, out: Path, *args: str) -> dict:
    """``sil run PATH ARGS`` in a process of its own; its summary, which must say completed."""
    summary = finished_run(path, out, *args)
    if summary.get("status") != "completed":
        raise BenchError(
            f"sil run {path.name} {' '.join(args)}: {summary.get('status')}, "
            f"{summary.get('abort_reason')}"
        )
    return summary
