"""Liveness of a lockstep run over the default udp_multicast bus: a node process stopped without
dying (SIGSTOP) aborts the run, named, within 5 s (its peer told, and recorded on its own clock),
and one stopped before it is ready ends the run within 10 s; a slow start, or a slow turn, that
keeps working is told from a stuck one; SIGTERM to `sil run` ends it as Ctrl-C does, with its own
reason; no child outlives the run."""

import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from sil.run.watchdog import ProcSample, Starting, StartWatch, TurnWatch, Watchdog, sample

SCENARIO = """
duration_s = 3000
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 92, 88]
step_s = 1
"""


def _pids(pattern: str) -> list[int]:
    found = subprocess.run(["pgrep", "-f", pattern], capture_output=True, text=True)
    return [int(p) for p in found.stdout.split()]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def _start(sil_process, tmp_path: Path, spec: str) -> tuple[subprocess.Popen, Path, list[int]]:
    """A 3000 s lockstep run over the udp bus (a minute or more: its nodes are still running when
    the recorder, at the lowest priority, has written the first trace), once it is going; with its
    children's PIDs."""
    path = tmp_path / "long.toml"
    path.write_text(SCENARIO)
    out = tmp_path / "run"
    proc = sil_process("run", str(path), "--bus", spec, "--out", str(out), "--no-plots")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        trace = out / "trace.csv"
        if trace.exists() and trace.stat().st_size > 200_000:
            children = [int(p) for p in subprocess.run(
                ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True
            ).stdout.split()]  # fmt: skip
            if len(children) != 3:  # the recorder, the plant and the ECU
                proc.kill()
                raise AssertionError(f"children of the run: {children}, not 3")
            return proc, out, children
        time.sleep(0.2)
    proc.kill()
    raise AssertionError("the run did not get going within 120 s")


def _ended(proc: subprocess.Popen, out: Path, spec: str, children: list[int]) -> dict:
    try:
        proc.communicate(timeout=60)
    finally:  # a run that hangs is ended here, its stopped children with it
        if proc.poll() is None:
            proc.kill()
            for pid in children:
                if _alive(pid):
                    os.kill(pid, signal.SIGKILL)
    assert proc.returncode == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted"
    assert not _pids(f"--bus {spec}")
    # no child outlives the run (by more than its interpreter's teardown, on a loaded machine)
    deadline = time.monotonic() + 5.0
    while [pid for pid in children if _alive(pid)] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in children if _alive(pid)]
    return summary


@pytest.mark.slow
@pytest.mark.parametrize(("victim", "name"), [("plant", "plant"), ("ecu", "ECU")])
def test_a_stopped_node_aborts_the_run_naming_it(tmp_path, victim, name, sil_process, udp_spec):
    spec = udp_spec()
    proc, out, children = _start(sil_process, tmp_path, spec)
    (pid,) = _pids(f"sil.cli {victim} --bus {spec}")
    os.kill(pid, signal.SIGSTOP)
    stopped = time.monotonic()
    while True:  # the run's own verdict, as soon as it is on disk
        summary = json.loads((out / "summary.json").read_text())
        if summary["status"] != "running" or time.monotonic() - stopped > 30:
            break
        time.sleep(0.05)
    took = time.monotonic() - stopped
    summary = _ended(proc, out, spec, children)
    match = re.fullmatch(
        rf"the {name} sent no frame for (\d+\.\d) s: its process is stopped \(process state T\)"
        r", at tick \d+ of \d+ \(\d+\.\d\d s simulated, \d+\.\d s after tick 0\)",
        summary["abort_reason"],
    )
    assert match is not None, summary["abort_reason"]
    assert 0.5 <= float(match.group(1)) <= 3.0  # found in its turn, stopped for 0.5 s
    assert took < 5.0, took  # found, its peer told and recorded, everything written
    assert summary["sim_time_s"] > 1.0 and summary["frames"] > 1000


@pytest.mark.slow
def test_sigterm_ends_the_run_as_ctrl_c_does_with_its_own_reason(tmp_path, sil_process, udp_spec):
    spec = udp_spec()
    proc, out, children = _start(sil_process, tmp_path, spec)
    proc.send_signal(signal.SIGTERM)
    summary = _ended(proc, out, spec, children)
    assert summary["abort_reason"] == "terminated (SIGTERM)"
    assert summary["frames"] > 1000 and (out / "can.log").stat().st_size > 10_000


class _Message:
    def __init__(self, frame_id: int, senders: list[str]) -> None:
        self.frame_id, self.senders = frame_id, senders


def test_the_watchdog_names_the_node_silent_too_long():
    from protocol.codec import Codec

    dog = Watchdog(Codec().messages, now=0.0)
    assert dog.node_of[0x100] == "plant" and dog.node_of[0x110] == "ECU"
    assert 0x80 not in dog.node_of  # the command node's own Demand owes nothing to anyone
    assert dog.silent({0x100: 3.9, 0x110: 3.9, 0x80: 3.9}, now=7.8) is None
    assert dog.silent({0x100: 7.9, 0x80: 7.9}, now=8.0) == (
        "the ECU sent no frame for 4.1 s (stopped or stuck)"
    )
    dog = Watchdog([_Message(1, ["Plant"]), _Message(2, ["ECU"])], now=10.0, silence_s=1.0)
    assert dog.silent({2: 10.5}, now=11.2) == "the plant sent no frame for 1.2 s (stopped or stuck)"


def _stopped_before_ready(
    sil_process, tmp_path: Path, spec: str
) -> tuple[subprocess.Popen, Path, float]:
    """A lockstep run whose plant process is stopped (SIGSTOP) as soon as it exists, before it
    is ready; with the time it was stopped."""
    out = tmp_path / "run"
    proc = sil_process("run", "start-nominal", "--bus", spec, "--out", str(out), "--no-plots")
    deadline = time.monotonic() + 60
    while not (found := _pids(f"sil.cli plant --bus {spec}")):
        if time.monotonic() > deadline or proc.poll() is not None:
            proc.kill()
            raise AssertionError("no plant process within 60 s")
        time.sleep(0.01)
    os.kill(found[0], signal.SIGSTOP)
    return proc, out, time.monotonic()


@pytest.mark.slow
def test_a_node_stopped_before_it_is_ready_ends_the_run_naming_it(tmp_path, udp_spec, sil_process):
    spec = udp_spec()
    proc, out, stopped = _stopped_before_ready(sil_process, tmp_path, spec)
    assert not (out / ".plant-ready").exists()  # stopped while it was starting
    try:
        _, stderr = proc.communicate(timeout=30)
    finally:
        proc.kill()
    took = time.monotonic() - stopped
    assert proc.returncode == 1 and took < 10.0, (took, stderr)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted"
    assert re.fullmatch(
        r"plant process did not come up: stopped \(process state T\) for 1\.\d s "
        r"\(see plant\.log\)",
        summary["abort_reason"],
    ), summary["abort_reason"]
    assert summary["abort_reason"] in stderr
    assert not _pids(f"--bus {spec}")  # the stopped plant was continued and ended


class _Sampler:
    """/proc as a test sets it: PID -> sample."""

    def __init__(self) -> None:
        self.now: dict[int, ProcSample] = {}

    def __call__(self, pids):
        return {pid: self.now[pid] for pid in pids if pid in self.now}


def _watch(sampler: _Sampler) -> StartWatch:
    return StartWatch(0.0, timeout_s=300.0, stopped_s=1.0, idle_s=5.0, sample_s=0.0,
                      sampler=sampler)  # fmt: skip


def test_a_slow_start_that_keeps_working_is_left_alone_up_to_the_limit():
    sampler = _Sampler()
    watch = _watch(sampler)
    for t in range(0, 300, 2):  # numba compiling for minutes: its CPU time advances
        sampler.now[1] = ProcSample("S", t, working=False)
        assert watch.check({"plant": Starting(1, None, False)}, float(t)) is None
    sampler.now[1] = ProcSample("R", 400, working=True)
    assert watch.check({"plant": Starting(1, None, False)}, 301.0) == (
        "plant",
        "not ready within 300 s",
    )


def test_a_start_that_sleeps_is_stuck_and_a_stopped_one_stopped():
    sampler = _Sampler()
    watch = _watch(sampler)
    nodes = {"ecu": Starting(2, None, True), "plant": Starting(1, None, False)}
    sampler.now = {1: ProcSample("S", 50, False), 2: ProcSample("S", 9, False)}
    for t in (0.0, 2.0, 4.9):  # the ready ECU sleeps waiting for the plant: that is its job
        assert watch.check(nodes, t) is None
    sampler.now[1] = ProcSample("S", 50, True)  # a child compiling, or reading the disk
    assert watch.check(nodes, 5.5) is None
    sampler.now[1] = ProcSample("S", 50, False)
    assert watch.check(nodes, 10.0) is None
    assert watch.check(nodes, 10.6) == (
        "plant",
        "no progress for 5.1 s (asleep, using no CPU time)",
    )
    watch = _watch(sampler)
    sampler.now[2] = ProcSample("T", 9, False)  # stopped: ready or not, it ends the start-up
    assert watch.check(nodes, 0.0) is None
    assert watch.check(nodes, 1.2) == ("ecu", "stopped (process state T) for 1.2 s")
    exited = {"ecu": Starting(2, None, True), "plant": Starting(1, 2, False)}
    assert _watch(sampler).check(exited, 0.0) == ("plant", "exited with code 2")


def test_proc_shows_a_sleeping_and_a_stopped_process():
    child = subprocess.Popen(["sleep", "30"])
    try:
        time.sleep(0.2)
        got = sample([child.pid, 2**22 + 1])
        assert set(got) == {child.pid}  # no such PID: left out
        assert got[child.pid].state == "S" and not got[child.pid].working
        os.kill(child.pid, signal.SIGSTOP)
        time.sleep(0.2)
        assert sample([child.pid])[child.pid].state == "T"
        # a process's own figures include its children's: this test's includes the sleep's
        assert sample([os.getpid()])[os.getpid()].cpu_ticks >= 0
    finally:
        child.kill()
        child.wait()


def _turns(sampler: _Sampler) -> TurnWatch:
    return TurnWatch({"plant": 1, "ecu": 2}, sample_s=0.0, sampler=sampler)


def test_a_slow_turn_is_waited_for_and_a_stopped_or_sleeping_node_is_dead():
    sampler = _Sampler()
    watch = _turns(sampler)
    assert watch.check("ecu", 10.0, 10.4) is None  # silent 0.4 s: not even looked at
    # a loaded machine: runnable but not running (no CPU time), or running slowly
    for t in range(1, 200):
        sampler.now[2] = ProcSample("R", 100, working=True)
        assert watch.check("ecu", 10.0, 10.0 + t) is None
    sampler.now[2] = ProcSample("S", 100 + 1, working=False)  # CPU time advanced: still slow
    assert watch.check("ecu", 10.0, 210.0) is None
    assert watch.check("ecu", 10.0, 211.9) is None  # asleep, no CPU time for 1.9 s
    assert watch.check("ecu", 10.0, 212.1) == (
        "the ECU sent no frame for 202.1 s: its process is asleep and used no CPU time for "
        "2.1 s (stuck)"
    )
    assert watch.looked == 1
    sampler.now[1] = ProcSample("T", 7, working=False)
    watch = _turns(sampler)
    assert watch.check("plant", 0.0, 0.6) is None
    assert watch.check("plant", 0.0, 1.0) is None
    assert watch.check("plant", 0.0, 1.2) == (
        "the plant sent no frame for 1.2 s: its process is stopped (process state T)"
    )


def test_a_node_heard_again_is_judged_afresh_and_a_busy_one_only_up_to_the_limit():
    sampler = _Sampler()
    watch = _turns(sampler)
    sampler.now[2] = ProcSample("S", 5, working=False)
    assert watch.check("ecu", 0.0, 0.6) is None
    assert watch.check("ecu", 0.0, 2.0) is None
    assert watch.check("ecu", 2.5, 2.7) is None  # it answered: its next silence starts anew
    assert watch.check("ecu", 2.5, 3.2) is None
    assert watch.check("ecu", 2.5, 5.1) is None  # asleep 1.9 s of this turn only
    sampler.now[2] = ProcSample("R", 6, working=True)
    assert watch.check("ecu", 2.5, 302.6) == (
        "the ECU sent no frame for 300.1 s though its process kept running (stuck, not slow)"
    )
    blind = TurnWatch({"ecu": 2}, sample_s=0.0, sampler=lambda pids: {})  # no /proc
    assert blind.check("ecu", 0.0, 3.9) is None
    assert blind.check("ecu", 0.0, 4.1) == "the ECU sent no frame for 4.1 s (stopped or stuck)"
