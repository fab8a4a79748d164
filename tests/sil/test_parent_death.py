"""A node a run spawned stops when the run is gone, also when the run died before the node could
ask for the parent-death signal."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from sil.run.parent_death import PARENT_ENV, NodeStop

ROOT = Path(__file__).parents[2]

CHILD = """
import time
from sil.run.parent_death import NodeStop
stop = NodeStop()
while not stop.is_set():
    time.sleep(0.05)
"""

# spawns the child without the parent-death signal (as a run killed before its child asked for
# it) and ends at once
PARENT = """
import subprocess, sys, os
from sil.run.parent_death import child_env
child = subprocess.Popen([sys.executable, "-c", sys.argv[1]], env={**os.environ, **child_env()})
print(child.pid, flush=True)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"  # a zombie has ended; its new parent reaps it


def test_the_stop_follows_the_parent(monkeypatch) -> None:
    monkeypatch.delenv(PARENT_ENV, raising=False)
    assert not NodeStop().is_set()  # started by hand: no parent to follow
    monkeypatch.setenv(PARENT_ENV, str(os.getppid()))
    stop = NodeStop()
    assert not stop.is_set()
    stop.set()
    assert stop.is_set()
    monkeypatch.setenv(PARENT_ENV, str(os.getpid()))  # not this process's parent: it is gone
    assert NodeStop().is_set()


def test_a_node_whose_run_died_first_stops() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", PARENT, CHILD], env=env, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    pid = int(done.stdout)
    deadline = time.monotonic() + 20.0
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = _alive(pid)
    if alive:
        os.kill(pid, 9)
    assert not alive
