"""Liveness of a run on a bus: every node owes frames, a node process starting up owes progress,
and SIGTERM ends a run as Ctrl-C does.

A node process that stops answering without dying (SIGSTOP, a deadlock) would otherwise leave
``sil run`` waiting: its peer runs on its own clock after the guard time and the run never ends.
The command node hears every frame on the bus, so the run keeps, per frame ID, when it last heard
it (wall clock) and, every check, which node has sent nothing of what the DBC says it sends for
:data:`SILENCE_S`.

Before tick 0 a node owes no frames but its start-up: :class:`StartWatch` tells a node process
that is slow to start (its CPU time, or its children's, advances) from one that exited, is
stopped (SIGSTOP) or sleeps without doing anything, from /proc (elsewhere: exits and the overall
limit only).

In lockstep (without bus faults) the same holds mid-run: :class:`TurnWatch` looks, in /proc, at
the node whose turn it is (the one that owes the next frame) once it has been silent for
:data:`LOOK_S`. Stopped, or asleep without using CPU time, it is dead; running or using CPU time
(a loaded machine), it is slow and waited for, however long, up to :data:`SLOW_LIMIT_S`. The
silence of :class:`Watchdog` is then left to real-time runs and runs with bus faults, whose
nodes run on their own clocks.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from pathlib import Path

SILENCE_S = 4.0  # checked every 0.2 s: a stuck node is found within 4.2 s of its last frame
NODES = {"Plant": "plant", "ECU": "ECU"}  # DBC sender -> the name the abort reason gives


class Terminated(KeyboardInterrupt):
    """SIGTERM: the run ends as on Ctrl-C, with its own reason."""


def interrupt_reason(exc: KeyboardInterrupt) -> str:
    return "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted (Ctrl-C)"


class Watchdog:
    """Which node sends which frame IDs (``messages``: the codec's, with ``frame_id`` and
    ``senders``), and when each node was last heard."""

    def __init__(self, messages, now: float, silence_s: float = SILENCE_S) -> None:
        self.silence_s = silence_s
        self.node_of = {m.frame_id: NODES[s] for m in messages for s in m.senders if s in NODES}
        self.heard_at = dict.fromkeys(NODES.values(), now)
        self.silent_node: str | None = None  # the node process found silent (plant, ecu)

    def silent(self, seen: dict[int, float], now: float) -> str | None:
        """The reason to abort if a node has been silent too long, else None. ``seen``: when
        each frame ID was last heard (other IDs are ignored)."""
        for frame_id, at in seen.items():
            node = self.node_of.get(frame_id)
            if node is not None and at > self.heard_at[node]:
                self.heard_at[node] = at
        for node, at in self.heard_at.items():
            if now - at > self.silence_s:
                self.silent_node = node.lower()
                return f"the {node} sent no frame for {now - at:.1f} s (stopped or stuck)"
        return None


START_TIMEOUT_S = 300.0  # a node process at work all along must be ready by then (numba in a VM)
STOPPED_S = 1.0  # a node process stopped (SIGSTOP, state T) this long ends the start-up
IDLE_S = 5.0  # ... or one asleep this long with no CPU time, nor any of its children's
SAMPLE_S = 0.25  # how often the processes are looked at in /proc
WORKING = frozenset("RD")  # /proc states of a process at work: running, or waiting on the disk


@dataclass(frozen=True)
class ProcSample:
    """A process as /proc shows it: its state letter, and the CPU time it and its descendants
    used (clock ticks), with whether one of them is at work (running or in disk I/O)."""

    state: str
    cpu_ticks: int
    working: bool


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state first), or None."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text.rsplit(")", 1)[1].split()


def sample(pids: Collection[int]) -> dict[int, ProcSample]:
    """The processes ``pids``, each with its descendants, as /proc shows them (a PID without an
    entry, or every PID where there is no /proc, is left out)."""
    try:
        entries = [int(e.name) for e in Path("/proc").iterdir() if e.name.isdigit()]
    except OSError:
        return {}
    table = {pid: f for pid in entries if (f := _stat_fields(pid)) is not None}
    children: dict[int, list[int]] = {}
    for child, fields in table.items():
        children.setdefault(int(fields[1]), []).append(child)
    out = {}
    for pid in pids:
        if pid not in table:
            continue
        tree, todo = [], [pid]
        while todo:
            current = todo.pop()
            tree.append(table[current])
            todo += children.get(current, [])
        # utime and stime: fields 14 and 15 of stat, 12 and 13 after the command name
        cpu = sum(int(f[11]) + int(f[12]) for f in tree)
        out[pid] = ProcSample(table[pid][0], cpu, any(f[0] in WORKING for f in tree))
    return out


@dataclass
class _Progress:
    cpu_ticks: int
    since: float  # when it last did some work
    stopped_since: float | None = None


@dataclass(frozen=True)
class Starting:
    """A node process during the start-up: its PID, exit code (None while it runs) and
    whether it has said it is ready."""

    pid: int
    exit_code: int | None
    ready: bool


class StartWatch:
    """Why a node process should end the run's start-up, if one should: it exited; it is
    stopped (SIGSTOP) for ``stopped_s``; not yet ready, it has slept for ``idle_s`` without
    using CPU time (nor its children: a compiler, QEMU) or being at work; or it is not ready
    after ``timeout_s`` however busy. A slow start that keeps working (numba compiling in a
    slow VM) is left alone up to that limit; a ready one waits for the others."""

    def __init__(
        self,
        now: float,
        *,
        timeout_s: float = START_TIMEOUT_S,
        stopped_s: float = STOPPED_S,
        idle_s: float = IDLE_S,
        sample_s: float = SAMPLE_S,
        sampler: Callable[[Collection[int]], dict[int, ProcSample]] = sample,
    ) -> None:
        self.started = now
        self.timeout_s, self.stopped_s, self.idle_s = timeout_s, stopped_s, idle_s
        self.sample_s, self.sampler = sample_s, sampler
        self._next_sample = now
        self._seen: dict[int, _Progress] = {}

    def check(self, nodes: dict[str, Starting], now: float) -> tuple[str, str] | None:
        """The first node that must end the start-up and why, or None."""
        for name, node in nodes.items():
            if node.exit_code is not None:
                return name, f"exited with code {node.exit_code}"
            if not node.ready and now - self.started > self.timeout_s:
                return name, f"not ready within {self.timeout_s:g} s"
        if now < self._next_sample:
            return None
        self._next_sample = now + self.sample_s
        samples = self.sampler([n.pid for n in nodes.values()])
        for name, node in nodes.items():
            got = samples.get(node.pid)
            why = None if got is None else self._judge(node, got, now)
            if why is not None:
                return name, why
        return None

    def _judge(self, node: Starting, got: ProcSample, now: float) -> str | None:
        seen = self._seen.setdefault(node.pid, _Progress(got.cpu_ticks, now))
        if got.state in "Tt":
            if seen.stopped_since is None:
                seen.stopped_since = now
            if now - seen.stopped_since >= self.stopped_s:
                return f"stopped (process state {got.state}) for {now - seen.stopped_since:.1f} s"
            return None
        seen.stopped_since = None
        if node.ready or got.cpu_ticks != seen.cpu_ticks or got.working:
            seen.cpu_ticks, seen.since = got.cpu_ticks, now
        elif now - seen.since >= self.idle_s:
            return f"no progress for {now - seen.since:.1f} s (asleep, using no CPU time)"
        return None


LOOK_S = 0.5  # a node silent this long in its turn is looked at in /proc
TURN_STOPPED_S = 0.5  # ... and dead once stopped (state T) this long
TURN_IDLE_S = 2.0  # ... and dead once asleep this long using no CPU time (nor its children)
SLOW_LIMIT_S = 300.0  # a node silent this long in its turn is stuck, however busy
NAMES = {"plant": "plant", "ecu": "ECU"}  # node process -> the name the abort reason gives


class TurnWatch:
    """Lockstep liveness mid-run: why the run must end because the node that owes the next
    frame is dead, or None. ``pids``: node process name (plant, ecu) -> its PID. Per check,
    the caller gives the node whose turn it is and when it was last heard (or its turn began,
    if later):

    - silent less than ``look_s``: fine;
    - stopped (SIGSTOP, state T) for ``stopped_s``: dead;
    - asleep (not running, not in disk I/O) with no CPU time used, by it or its children (the
      PIL image's QEMU), for ``idle_s``: dead (stuck, waiting on nothing the run sends);
    - otherwise slow, and waited for, up to ``slow_limit_s`` of silence.

    Where /proc does not show the process, ``fallback_s`` of silence ends the run."""

    def __init__(
        self,
        pids: Mapping[str, int],
        *,
        look_s: float = LOOK_S,
        stopped_s: float = TURN_STOPPED_S,
        idle_s: float = TURN_IDLE_S,
        slow_limit_s: float = SLOW_LIMIT_S,
        fallback_s: float = SILENCE_S,
        sample_s: float = SAMPLE_S,
        sampler: Callable[[Collection[int]], dict[int, ProcSample]] = sample,
    ) -> None:
        self.pids = dict(pids)
        self.look_s, self.stopped_s, self.idle_s = look_s, stopped_s, idle_s
        self.slow_limit_s, self.fallback_s = slow_limit_s, fallback_s
        self.sample_s, self.sampler = sample_s, sampler
        self._next_sample = 0.0
        self._node: str | None = None
        self._seen: _Progress | None = None
        self.looked = 0  # turns in which a silent node was looked at (and found slow, or dead)

    def check(self, node: str, silent_since: float, now: float) -> str | None:
        """Why ``node``, whose turn it is and which has been silent since ``silent_since``,
        is dead; None while it is (or may be) alive."""
        silent = now - silent_since
        if silent < self.look_s:
            if self._node == node:
                self._node, self._seen = None, None
            return None
        name = NAMES.get(node, node)
        if silent > self.slow_limit_s:
            return (
                f"the {name} sent no frame for {silent:.1f} s though its process kept running "
                "(stuck, not slow)"
            )
        if now < self._next_sample and self._node == node:
            return None
        self._next_sample = now + self.sample_s
        pid = self.pids.get(node)
        got = self.sampler([pid]).get(pid) if pid is not None else None
        if got is None:  # no /proc to tell (or the process is gone: its exit says so)
            if silent > self.fallback_s:
                return f"the {name} sent no frame for {silent:.1f} s (stopped or stuck)"
            return None
        return self._judge(node, name, got, silent, now)

    def _judge(
        self, node: str, name: str, got: ProcSample, silent: float, now: float
    ) -> str | None:
        if self._node != node or self._seen is None:
            self._node, self._seen = node, _Progress(got.cpu_ticks, now)
            self.looked += 1
        seen = self._seen
        if got.state in "Tt":
            if seen.stopped_since is None:
                seen.stopped_since = now
            if now - seen.stopped_since >= self.stopped_s:
                return (
                    f"the {name} sent no frame for {silent:.1f} s: its process is stopped "
                    f"(process state {got.state})"
                )
            return None
        seen.stopped_since = None
        if got.cpu_ticks != seen.cpu_ticks or got.working:
            seen.cpu_ticks, seen.since = got.cpu_ticks, now
        elif now - seen.since >= self.idle_s:
            return (
                f"the {name} sent no frame for {silent:.1f} s: its process is asleep and used "
                f"no CPU time for {now - seen.since:.1f} s (stuck)"
            )
        return None
