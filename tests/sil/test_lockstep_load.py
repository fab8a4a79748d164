"""A lockstep run does not depend on the machine being quiet: beside twice as many busy processes
as there are cores, a run on the loopback bus is slower, and nothing else: the can.log of the run
on a quiet machine, byte for byte, no missed tick, no node on its own clock. A node stopped mid-run
on that machine is still found and named within 5 s."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import pytest

from sil import scenario as scenarios
from sil.run.run_record import scenario_text

LOAD_S = 600  # the busy processes end on their own after this, whatever happens to the test


@contextmanager
def _busy(count: int) -> Iterator[list[subprocess.Popen]]:
    """``count`` processes spinning on a core each (at the default priority), for at most
    LOAD_S, always ended when the block is left."""
    spin = f"import time\nend = time.monotonic() + {LOAD_S}\nwhile time.monotonic() < end: pass"
    procs = [subprocess.Popen([sys.executable, "-c", spin]) for _ in range(count)]
    try:
        time.sleep(0.5)
        assert all(p.poll() is None for p in procs)
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def _cut(tmp_path: Path, duration: float) -> Path:
    s = scenarios.load("thesis-5.4-staircase")
    path = tmp_path / f"staircase-{duration:g}.toml"
    path.write_text(scenario_text(replace(s, duration_s=duration), s.seed))
    return path


def _run(sil, path: Path, out: Path, spec: str) -> dict:
    result = sil("run", str(path), "--bus", spec, "--out", str(out), "--no-plots", timeout=900)
    assert "Traceback" not in result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert result.returncode == (0 if summary["status"] == "completed" else 1)
    return summary


@pytest.mark.slow
def test_a_lockstep_run_beside_busy_processes_is_the_quiet_machines_run(
    tmp_path, udp_spec, sil, first_difference
):
    path = _cut(tmp_path, 10.0)
    quiet = _run(sil, path, tmp_path / "quiet", udp_spec())
    assert quiet["status"] == "completed" and quiet["missed_ticks"] == 0
    with _busy(2 * (os.cpu_count() or 1)):
        loaded = _run(sil, path, tmp_path / "loaded", udp_spec())
    print(f"quiet {quiet['wall_time_s']:.1f} s, loaded {loaded['wall_time_s']:.1f} s (start-up "
          f"{loaded['startup_s']:.1f} s), slow turns {loaded.get('slow_turns', 0)}")  # fmt: skip
    assert loaded["status"] == "completed", loaded["abort_reason"]
    assert loaded["missed_ticks"] == 0
    nodes = loaded["nodes"]  # nobody ran on its own clock (the ECU's guard timeouts count its
    # XCP slave's polls before the first sensor frame too; the identical log below tells)
    assert nodes["plant"]["guard_timeouts"] == 0
    assert nodes["ecu"]["ticks_without_due_demand"] == 0
    logs = [(tmp_path / r / "can.log").read_bytes() for r in ("quiet", "loaded")]
    assert first_difference(*logs) is None


def _pids(pattern: str) -> list[int]:
    found = subprocess.run(["pgrep", "-f", pattern], capture_output=True, text=True)
    return [int(p) for p in found.stdout.split()]


@pytest.mark.slow
def test_an_ecu_stopped_on_a_loaded_machine_is_found_and_named_within_5_s(tmp_path, udp_spec):
    path = _cut(tmp_path, 3000.0)
    spec, out = udp_spec(), tmp_path / "run"
    with _busy(2 * (os.cpu_count() or 1)):
        proc = subprocess.Popen(
            [sys.executable, "-m", "sil.cli", "run", str(path), "--bus", spec, "--out", str(out),
             "--no-plots"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 600
            while not ((out / "trace.csv").exists() and (out / "trace.csv").stat().st_size > 1e5):
                assert time.monotonic() < deadline and proc.poll() is None
                time.sleep(0.1)
            (ecu,) = _pids(f"sil.cli ecu --bus {spec}")
            os.kill(ecu, signal.SIGSTOP)
            stopped = time.monotonic()
            while json.loads((out / "summary.json").read_text())["status"] == "running":
                assert time.monotonic() - stopped < 60
                time.sleep(0.05)
            took = time.monotonic() - stopped
            proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    summary = json.loads((out / "summary.json").read_text())
    print(f"found and written in {took:.1f} s: {summary['abort_reason']}")
    assert proc.returncode == 1 and summary["status"] == "aborted"
    assert re.fullmatch(
        r"the ECU sent no frame for \d+\.\d s: its process is stopped \(process state T\), "
        r"at tick \d+ of \d+ \(\d+\.\d\d s simulated, \d+\.\d s after tick 0\)",
        summary["abort_reason"],
    ), summary["abort_reason"]
    assert took < 5.0
    assert not _pids(f"--bus {spec}")  # the stopped ECU was continued and ended
