"""Liveness of a lockstep run over the default udp_multicast bus: a node process stopped without
dying (SIGSTOP) aborts the run, named, within 5 s of its last frame; SIGTERM to `sil run` ends it
as Ctrl-C does, with its own reason; no child outlives the run."""

import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sil.watchdog import Watchdog

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


def _udp_spec() -> str:
    rng = random.Random(os.getpid() ^ time.time_ns())
    return (
        f"udp:239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}@{rng.randrange(20000, 60000)}"
    )


def _pids(pattern: str) -> list[int]:
    found = subprocess.run(["pgrep", "-f", pattern], capture_output=True, text=True)
    return [int(p) for p in found.stdout.split()]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def _start(tmp_path: Path, spec: str) -> tuple[subprocess.Popen, Path, list[int]]:
    """A 3000 s lockstep run over the udp bus (a minute or more: its nodes are still running when
    the recorder, at the lowest priority, has written the first trace), once it is going; with its
    children's PIDs."""
    path = tmp_path / "long.toml"
    path.write_text(SCENARIO)
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sil.cli", "run", str(path), "--bus", spec, "--out", str(out),
         "--no-plots"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
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
def test_a_stopped_node_aborts_the_run_naming_it(tmp_path, victim, name):
    spec = _udp_spec()
    proc, out, children = _start(tmp_path, spec)
    (pid,) = _pids(f"sil.cli {victim} --bus {spec}")
    os.kill(pid, signal.SIGSTOP)
    stopped = time.monotonic()
    while True:  # the run's own verdict, as soon as it is on disk
        summary = json.loads((out / "summary.json").read_text())
        if summary["status"] != "running" or time.monotonic() - stopped > 30:
            break
        time.sleep(0.1)
    took = time.monotonic() - stopped
    summary = _ended(proc, out, spec, children)
    match = re.fullmatch(rf"the {name} sent no frame for (\d+\.\d) s \(stopped or stuck\)",
                         summary["abort_reason"])  # fmt: skip
    assert match is not None, summary["abort_reason"]
    assert 4.0 <= float(match.group(1)) <= 5.0  # past 4 s (printed to 0.1 s), within 5
    assert took < 15.0  # found, the others stopped and everything written
    assert summary["sim_time_s"] > 1.0 and summary["frames"] > 1000


@pytest.mark.slow
def test_sigterm_ends_the_run_as_ctrl_c_does_with_its_own_reason(tmp_path):
    spec = _udp_spec()
    proc, out, children = _start(tmp_path, spec)
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
