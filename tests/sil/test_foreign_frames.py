"""Another sender on a run's bus: a recorded can.log played onto the loopback bus a lockstep run
is using (`sil replay LOG --bus SPEC`). The run completes as it would alone (the can.log of the
same run in process, byte for byte), counting the other sender's frames, or aborts naming them;
its can.log never holds one of them."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from sil import scenario as scenarios
from sil.run.run_record import scenario_text
from sil.run.runner import RunOptions, run


def _cut(tmp_path: Path, name: str, duration: float, seed: int) -> Path:
    s = scenarios.load(name)
    s = replace(s, duration_s=duration, seed=seed)
    path = tmp_path / f"{name}-{duration:g}-{seed}.toml"
    path.write_text(scenario_text(s, seed))
    return path


def _frames(log: Path) -> list[str]:
    """A candump log's frames as ``ID#DATA``, without their times."""
    return [line.split()[-1] for line in log.read_text().splitlines()]


def _replayable(tmp_path: Path) -> Path:
    """Another run's can.log (another seed), from its tick 2000 on: frames of every ID of the
    contract, with valid CRCs and counters, whose ticks a 10 s run never reaches."""
    s = scenarios.load(str(_cut(tmp_path, "thesis-5.4-staircase", 40.0, 3)))
    out = tmp_path / "other"
    assert run(RunOptions(s, out, mode="inproc", plots=False, progress=False))["status"] == (
        "completed"
    )
    lines = (out / "can.log").read_text().splitlines()
    start = next(
        i
        for i, line in enumerate(lines)
        if line.split()[-1].startswith("100#") and line.split()[-1][8:12] == "D007"
    )  # fmt: skip  (SensorTick 2000, little-endian)
    log = tmp_path / "other.log"
    log.write_text("\n".join(lines[start:]) + "\n")
    return log


@pytest.mark.slow
def test_a_log_played_onto_the_runs_bus_is_kept_out_of_the_run(tmp_path, udp_spec, sil):
    path = _cut(tmp_path, "thesis-5.4-staircase", 10.0, 1)
    quiet = tmp_path / "quiet"
    alone = run(RunOptions(scenarios.load(str(path)), quiet, mode="inproc", plots=False,
                           progress=False))  # fmt: skip
    assert alone["status"] == "completed"
    other = _replayable(tmp_path)
    spec = udp_spec()
    replay = subprocess.Popen(
        [sys.executable, "-m", "sil.cli", "replay", str(other), "--bus", spec, "--loop"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        time.sleep(1.0)  # it plays before the run's nodes start, and all through the run
        assert replay.poll() is None, replay.stderr.read() if replay.stderr else ""
        out = tmp_path / "shared"
        result = sil("run", str(path), "--bus", spec, "--out", str(out), "--no-plots", "--json",
                     timeout=600)  # fmt: skip
    finally:
        replay.terminate()
        try:
            replay.wait(10)
        except subprocess.TimeoutExpired:
            replay.kill()
            replay.wait()
    summary = json.loads((out / "summary.json").read_text())
    assert "Traceback" not in result.stderr
    assert summary["other_sender_frames"] > 0, summary  # the recorder heard them, and dropped
    assert summary["foreign_frames"] >= summary["other_sender_frames"]
    assert {"0x100", "0x110"} <= set(summary["other_sender_ids"])  # whatever their ID
    for node in ("plant", "ecu"):  # each node heard some of its own IDs and peers' too
        assert summary["nodes"][node]["other_sender_frames"] > 0, summary["nodes"][node]
    logged = _frames(out / "can.log")
    theirs = set(_frames(other)) - set(_frames(quiet / "can.log"))
    assert not theirs & set(logged)  # not one of them recorded
    if summary["status"] == "completed":
        assert result.returncode == 0
        assert (out / "can.log").read_bytes() == (quiet / "can.log").read_bytes()
        assert summary["missed_ticks"] == 0
        assert any(w.startswith("foreign frames on the bus: ") for w in summary["warnings"])
        assert "foreign frames on the bus: " in result.stderr
    else:
        assert result.returncode == 1
        assert summary["abort_reason"].startswith("foreign frames on the bus: "), summary
        assert "the run's bus is shared" in summary["abort_reason"]
