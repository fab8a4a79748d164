"""A run that ends before its last tick says which node ended it, when (the tick and the time)
and why (its exit code and last line, or a watch's verdict), in summary.json and on the terminal:
a node killed in a real-time run, and the reasons built for each way a run ends early."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pytest

from ecu.port import toolchain
from ecu.port.qemu import QEMU
from sil import scenario as scenarios
from sil.run import processes
from sil.run.run_record import scenario_text
from sil.run.state import RunState
from sil.run.summary import _ended_early


def _command(answered: int, ticks: int) -> SimpleNamespace:
    return SimpleNamespace(recorder=SimpleNamespace(tick=answered), last_tick=ticks - 1)


def _ending(tmp_path: Path, answered: int = 250, ticks: int = 1001) -> processes._Ending:
    state = RunState(nodes_up=time.perf_counter() - 3.0)  # tick 0 was 3 s ago
    return processes._Ending(state, _command(answered, ticks), 0.01, tmp_path)


def test_a_node_that_failed_is_named_with_its_code_its_last_line_and_when(tmp_path):
    (tmp_path / "plant.log").write_text("plant: starting\nsil plant: error: the bus is gone\n\n")
    ending = _ending(tmp_path)
    ending.end("plant", f"{processes._exit('plant', 2)} mid-run", code=2)
    state = ending.state
    assert state.status == "aborted"
    assert state.abort_reason.startswith(
        "plant process exited with code 2 mid-run, at tick 250 of 1001 (2.50 s simulated, 3."
    )
    assert state.abort_reason.endswith("after tick 0); its last line: sil plant: error: the bus "
                                       "is gone")  # fmt: skip
    ended = state.ended_early
    assert ended["node"] == "plant" and ended["exit_code"] == 2 and ended["tick"] == 250
    assert ended["time_s"] == pytest.approx(2.5) and 3.0 <= ended["wall_s"] < 4.0
    assert ended["last_line"] == "sil plant: error: the bus is gone"


def test_a_killed_node_is_named_with_the_signal_and_no_last_line(tmp_path):
    (tmp_path / "ecu.log").write_text("xcp: CAN IDs 0x700 (master) 0x701 (ECU)\n")
    ending = _ending(tmp_path)
    ending.end("ecu", f"{processes._exit('ecu', -9)} mid-run", code=-9)
    assert ending.state.abort_reason.startswith(
        "ecu process exited with code -9 (killed by SIGKILL) mid-run, at tick 250 of 1001"
    )
    assert "last line" not in ending.state.abort_reason  # (what it said before: not why)
    assert "last_line" not in ending.state.ended_early


def test_a_real_time_run_short_of_answers_says_when_they_stopped_or_how_far_behind(tmp_path):
    ending = _ending(tmp_path, answered=900)
    start = time.monotonic() - 10.0
    processes._short_of_ticks(ending, start + 8.0, start, 0.01)  # the last answer 2 s ago
    assert ending.state.abort_reason.startswith(
        "the ECU answered 900 of 1001 ticks by the end of the run's clock: its answers stopped "
        "2.0 s before it ended, at tick 900"
    )
    assert ending.state.ended_early["node"] == "ecu"
    behind = _ending(tmp_path, answered=950)
    processes._short_of_ticks(behind, time.monotonic(), time.monotonic() - 10.0, 0.01)
    assert behind.state.abort_reason.startswith(
        "the ECU answered 950 of 1001 ticks by the end of the run's clock: it fell 51 ticks "
        "behind (its answers came at 95.0 Hz, the run's rate is 100 Hz)"
    )


def test_the_summary_adds_the_pace_of_a_node_that_overran_its_periods():
    ended = {"node": "ecu", "tick": 950, "why": "the ECU answered 950 of 1001 ticks"}
    summary = {
        "abort_reason": "the ECU answered 950 of 1001 ticks, at tick 950",
        "nodes": {"ecu": {"periods": 940, "overruns": 12, "jitter_ms": {"max": 48.2}}},
    }
    assert _ended_early(ended, summary) == {**ended, "overruns": 12, "worst_lateness_ms": 48.2}
    assert summary["abort_reason"].endswith(
        "; its process overran 12 of 940 periods, 48 ms late at worst"
    )
    quiet = {"abort_reason": "x", "nodes": {"ecu": {"periods": 1001, "overruns": 0}}}
    assert _ended_early(ended, quiet) == ended and quiet["abort_reason"] == "x"


def _pid(spec: str, node: str) -> int:
    found = subprocess.run(
        ["pgrep", "-f", f"sil.cli {node} --bus {spec}"], capture_output=True, text=True
    ).stdout.split()
    assert len(found) == 1, f"{node} processes for {spec}: {found}"
    return int(found[0])


def _kill_in_a_real_time_run(
    tmp_path: Path, spec: str, sil_process, victim: Callable[[], int], *extra: str
) -> tuple[dict, str, float]:
    """A 3 s real-time run at 100 Hz (301 ticks) whose process ``victim()`` is killed 1 s after
    tick 0: its summary, its stderr, and when the kill came after tick 0."""
    s = replace(scenarios.load("thesis-5.4-staircase"), duration_s=3.0, seed=2)
    path = tmp_path / "short.toml"
    path.write_text(scenario_text(s, 2))
    out = tmp_path / "run"
    proc = sil_process("run", str(path), "--mode", "realtime", "--bus", spec, "--out", str(out),
                       "--no-plots", *extra)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not (out / ".plant-start").exists():  # tick 0 goes out now
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.01)
        started = time.monotonic()
        time.sleep(1.0)
        os.kill(victim(), signal.SIGKILL)
        killed = time.monotonic() - started
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 1
    return json.loads((out / "summary.json").read_text()), stderr, killed


@pytest.mark.slow
@pytest.mark.parametrize("victim", ["ecu", "plant"])
def test_a_node_killed_in_a_real_time_run_is_named_with_when_and_why(
    tmp_path, victim, udp_spec, sil_process
):
    spec = udp_spec()
    summary, stderr, killed = _kill_in_a_real_time_run(
        tmp_path, spec, sil_process, lambda: _pid(spec, victim)
    )
    assert summary["status"] == "aborted"
    ended = summary["ended_early"]
    assert ended["node"] == victim and ended["exit_code"] == -signal.SIGKILL
    assert killed - 0.3 <= ended["wall_s"] <= killed + 1.0, (killed, ended)  # (watched each 0.2 s)
    assert 0 < ended["tick"] < 301 and ended["time_s"] == pytest.approx(ended["tick"] / 100.0)
    reason = summary["abort_reason"]
    assert reason.startswith(
        f"{victim} process exited with code -9 (killed by SIGKILL) mid-run, at tick "
        f"{ended['tick']} of 301 ({ended['time_s']:.2f} s simulated, {ended['wall_s']:.1f} s "
        "after tick 0)"
    ), reason
    assert f"sil run: aborted: {reason}" in stderr


@pytest.mark.slow
def test_the_emulator_killed_under_the_image_in_real_time_ends_the_run_naming_it(
    tmp_path, udp_spec, sil_process
):
    """`sil run --mode realtime --ecu-impl pil`, its QEMU killed: the ECU process ends saying
    so, and the run names the ECU, when, its exit code and that last line."""
    try:
        toolchain.ensure()
    except toolchain.ToolchainError as exc:
        pytest.fail(f"C port toolchains: {exc}")
    spec = udp_spec()

    def qemu() -> int:
        found = subprocess.run(["pgrep", "-P", str(_pid(spec, "ecu")), "-f", QEMU],
                               capture_output=True, text=True).stdout.split()  # fmt: skip
        assert len(found) == 1, found
        return int(found[0])

    summary, stderr, killed = _kill_in_a_real_time_run(
        tmp_path, spec, sil_process, qemu, "--ecu-impl", "pil"
    )
    ended = summary["ended_early"]
    said = "sil ecu: --impl pil: the emulator exited with code -9 while the image ran"
    assert ended["node"] == "ecu" and ended["exit_code"] == 2 and ended["last_line"] == said
    assert killed - 0.3 <= ended["wall_s"] <= killed + 1.0, (killed, ended)
    assert summary["abort_reason"].startswith(
        f"ecu process exited with code 2 mid-run, at tick {ended['tick']} of 301 ("
    )
    assert summary["abort_reason"].endswith(f"; its last line: {said}")
    assert f"sil run: aborted: {summary['abort_reason']}" in stderr
