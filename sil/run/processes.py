"""The node processes of a run on a bus: spawned, started together (ready and start
files), listened to by the command node, watched (a node that exits, stops or falls silent),
told when their peer is dead, and stopped."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import can

from protocol.bus import BusSpec, open_bus
from protocol.node import DriverStats, bus_batch_receiver, bus_sender, unusable
from protocol.run_bus import RunBus
from protocol.run_sequence import RunSequence, sent_by
from sil.busfault.bridge import Bridge, SensorTicks, WallTicks
from sil.busfault.injector import Injector
from sil.record.ticks import ACTUATOR, ECU_IDS, PLANT_IDS, SENSORS
from sil.run.command_node import CommandNode
from sil.run.config import NODE_GUARD_S, RunOptions, ready_file, start_file, stats_file, strict
from sil.run.membership import give_start, sender_in
from sil.run.parent_death import PEER_LOST_SIGNAL, child_env, die_with_parent
from sil.run.state import RunState
from sil.run.watchdog import Starting, StartWatch, TurnWatch, Watchdog
from sil.scenario import Scenario

GRACE_S = NODE_GUARD_S + 2.0  # recording continues this long after a node died


PEER_GRACE_S = 0.5  # ... then records this long, the node on its own clock, before it ends


# lockstep on a bus that hands over every frame queued at once (the loopback bus): the command
# node reads it at most this often while frames come; they queue in between, so that one read
# takes a tick's frames and no sender has to wake this process for each of them
LOCKSTEP_READ_S = 100e-6


READY_POLL_S = 0.02  # how often the start-up looks at the node processes


STOPPED_ANSWERS_S = 0.5  # real time: the ECU's answers stopped this long before the run's end
CLEAN_END_TICKS = 10  # real time: a node may end cleanly this many ticks before the run's last
QUEUED_S = 0.1  # real time: the frames queued at the run's end are read for at most this long


def spawn(name: str, args: list[str], out_dir: Path) -> subprocess.Popen:
    log = (out_dir / f"{name}.log").open("w")
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **child_env()}
    return subprocess.Popen(
        [sys.executable, "-m", "sil.cli", *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        env=env,
        preexec_fn=die_with_parent if sys.platform == "linux" else None,  # (before exec)
    )


def stop(children: dict[str, subprocess.Popen]) -> None:
    for proc in children.values():
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.send_signal(signal.SIGCONT)  # a stopped process takes the SIGTERM then
    deadline = time.monotonic() + 3.0
    for proc in children.values():
        try:
            proc.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_on_bus(
    opts: RunOptions,
    s: Scenario,
    seed: int,
    specs: tuple[BusSpec, BusSpec],
    command: CommandNode,
    state: RunState,
) -> None:
    """The node processes are starting (see ``_run``): wait until both are ready, then play.
    ``specs``: the run's bus and the ECU's (the same bus unless there are bus faults)."""
    spec, ecu_spec = specs
    tags = [claim.tag for claim in state.claims]
    codec = command.codec
    own = sent_by(codec, "Command")
    sequence = RunSequence(codec, s.ecu_rate_hz, own, strict=strict(opts, s))
    with RunBus(state.take_bus(), tags[0], sequence) as bus, ExitStack() as stack:
        state.run_bus = bus
        if s.bus_faults:
            injector = Injector(s.bus_faults, s.ecu_rate_hz, seed, command.codec)
            state.bus_fault_events = injector.events
            clock = WallTicks(s.ecu_rate_hz) if opts.mode == "realtime" else SensorTicks()
            plant_side = stack.enter_context(RunBus(open_bus(spec), tags[0]))
            ecu_side = stack.enter_context(RunBus(open_bus(ecu_spec), tags[-1]))
            bridge = stack.enter_context(Bridge(plant_side, ecu_side, injector, ticks=clock))
            state.bridge_errors = bridge.errors
            state.ecu_heard = bridge.ecu_side_heard  # the ECU's frames before the injector
        # once both are ready (each listening on the bus; the plant built and waiting for its
        # start file, keeping what it hears meanwhile), the frames due before tick 0 go out and
        # the plant sends tick 0: in real time too, the ECU is armed only when the engine's
        # frames are coming
        failed = _wait_until_ready(opts.out_dir, state.children)
        if failed is not None:
            state.status, state.abort_reason = "aborted", failed
            return
        # who belongs to the run, agreed before tick 0: from now on its nodes and this one (and
        # so the recorder) hear only each other, where the bus names senders
        senders = {} if s.bus_faults else _run_senders(opts.out_dir, state.children, bus)
        if senders and bus.admit(senders.values()):
            state.senders = senders
        _drain(bus)
        send = bus_sender(bus, DriverStats())
        command.start(send)
        give_start(start_file(opts.out_dir), state.senders or {})
        state.nodes_up = time.perf_counter()
        _listen(
            bus,
            command,
            state,
            send,
            realtime=opts.mode == "realtime",
            period=1.0 / s.ecu_rate_hz,
            turns=strict(opts, s),
            logs=opts.out_dir,
        )


def _wait_until_ready(out_dir: Path, children: dict[str, subprocess.Popen]) -> str | None:
    """Wait until every node process has said it is ready; else why the run cannot begin, naming
    the node (:class:`sil.run.watchdog.StartWatch`: it exited, is stopped, makes no progress or is
    not ready within the overall limit)."""
    watch = StartWatch(time.monotonic())
    while True:
        ready = {name: ready_file(out_dir, name).exists() for name in children}
        if all(ready.values()):
            return None
        nodes = {n: Starting(p.pid, p.poll(), ready[n]) for n, p in children.items()}
        failed = watch.check(nodes, time.monotonic())
        if failed is not None:
            name, why = failed
            said = "" if why.startswith("stopped") else _last_line(out_dir / f"{name}.log")
            return f"{name} process did not come up: {why}{f': {said}' if said else ''} " + (
                f"(see {name}.log)"
            )
        time.sleep(READY_POLL_S)


def _run_senders(
    out_dir: Path, children: dict[str, subprocess.Popen], bus: RunBus
) -> dict[str, str]:
    """The run's senders by their tokens (this command node's and each node's, from its ready
    file); none unless every one has a token (frames on this bus name their sender)."""
    senders = {"command": bus.sender} | {n: sender_in(ready_file(out_dir, n)) for n in children}
    if any(token is None for token in senders.values()):
        return {}
    return {name: token for name, token in senders.items() if token is not None}


def _last_line(log: Path) -> str:
    """The last line a node wrote to its log (why it stopped), or ""."""
    try:
        lines = log.read_text(errors="replace").split("\n")
    except OSError:
        return ""
    return next((line.strip() for line in reversed(lines) if line.strip()), "")


def _drain(bus: can.BusABC) -> None:
    """Drop the frames queued before the run starts: an ECU on its own clock (real time, or
    past its guard time while the plant builds) talks before there is an engine."""
    receive = bus_batch_receiver(bus)
    while receive(0.0):
        pass


def node_stats(out_dir: Path) -> dict[str, dict]:
    """The node processes' own summaries: frames, timeouts; in real time jitter and overruns."""
    stats = {}
    for node in ("ecu", "plant"):
        path = stats_file(out_dir, node)
        try:
            stats[node] = json.loads(path.read_text())
        except (OSError, ValueError):
            continue  # a node that died mid-run leaves none
        finally:
            path.unlink(missing_ok=True)
    return stats


def _listen(
    bus: can.BusABC,
    command: CommandNode,
    state: RunState,
    send,
    *,
    realtime: bool,
    period: float,
    turns: bool = False,
    logs: Path,
) -> None:
    """The command node's loop: frames in (all those queued at each read), and a watch on the
    node processes. One that exits aborts the run; so does one that falls silent: with
    ``turns`` (lockstep without bus faults) the node whose turn it is, once /proc shows it dead
    (:class:`sil.run.watchdog.TurnWatch`; a slow one is waited for), its peer then told and
    recorded on its own clock for PEER_GRACE_S; else one that sends nothing for
    ``watchdog.SILENCE_S``, its peer having run on its own clock since its guard time. The
    abort names the node, when and why (:class:`_Ending`); ``logs``: the nodes' logs' folder."""
    ending = _Ending(state, command, period, logs)
    died_at = None
    receive = bus_batch_receiver(bus)
    paced = not realtime and getattr(bus, "recv_frames", None) is not None
    start = time.monotonic()
    next_period = next_check = start
    dog = Watchdog(command.codec.messages, start)
    seen: dict[int, float] = {}  # frame ID -> when last heard
    watch = _TurnState(state.children, start) if turns else None
    state.turn_watch = watch.watch if watch is not None else None
    grace = PEER_GRACE_S if turns else GRACE_S
    drained = False  # the last read found no frame queued: what was heard is up to date
    while not command.finished:
        now = time.monotonic()
        if realtime and now >= next_period:
            command.on_period(send, now - start)
            next_period += period
            continue
        if now >= next_check:
            next_check = now + 0.2
            if died_at is None:
                left = command.last_tick - command.own_tick if realtime else None
                died_at = _node_exited(state, ending, now, left)
                if died_at is None and watch is None:
                    if (silent := _silent(dog, seen, state, now)) is not None:
                        ending.end(dog.silent_node or "a node", silent)
                        return  # its peer has run on its own clock since its guard time
                elif died_at is None and drained and (dead := watch.dead(now)) is not None:
                    ending.end(watch.node, dead)
                    died_at = now
                if died_at is not None and watch is not None and state.status == "aborted":
                    _peer_lost(state, bus)
            elif now - died_at > (grace if state.status == "aborted" else GRACE_S):
                if state.status != "aborted":  # it ended cleanly, and the run's end never came
                    _ended_early(state, ending)
                return
        frames = receive(min(0.05, next_period - now) if realtime else 0.05)
        drained = not frames
        for got in frames:
            if type(got) is not tuple:
                if unusable(got) is not None:
                    continue
                got = (got.arbitration_id, got.data)
            seen[got[0]] = now
            if watch is not None:
                watch.heard(got[0], now)
            wall_s = time.monotonic() - start if realtime else None
            command.on_frame(got[0], got[1], send, wall_s=wall_s)
            if command.finished:
                return
        if frames and paced:
            time.sleep(LOCKSTEP_READ_S)
    if realtime and command.recorder.tick <= command.last_tick and state.status != "aborted":
        last = _queued_answers(receive, command, send, start) or seen.get(ACTUATOR)
        if command.recorder.tick <= command.last_tick:
            _short_of_ticks(ending, last, start, period)


def _queued_answers(receive, command: CommandNode, send, start: float) -> float | None:
    """Real time, the run's clock run out: the frames queued meanwhile (a command node that got
    its core late runs its clock's last periods before it reads them), heard before the run is
    judged; when the last EcuActuator among them was read, if one was."""
    last, deadline = None, time.monotonic() + QUEUED_S
    while (frames := receive(0.0)) and time.monotonic() < deadline:
        for got in frames:
            if type(got) is not tuple:
                if unusable(got) is not None:
                    continue
                got = (got.arbitration_id, got.data)
            now = time.monotonic()
            command.on_frame(got[0], got[1], send, wall_s=now - start)
            if got[0] == ACTUATOR:
                last = now
                if command.recorder.tick > command.last_tick:  # the last tick answered
                    return last
    return last


class _TurnState:
    """Whose turn it is in lockstep, as the command node hears the run (the plant's after
    EcuActuator(k), the ECU's after PlantSensors(k)), and since when that node has been silent;
    :class:`sil.run.watchdog.TurnWatch` judges it."""

    def __init__(self, children: dict[str, subprocess.Popen], now: float) -> None:
        self.watch = TurnWatch({name: proc.pid for name, proc in children.items()})
        self.node = "plant"  # tick 0 is the plant's
        self.since = now
        self._of = {i: "plant" for i in PLANT_IDS} | {i: "ecu" for i in ECU_IDS}

    def heard(self, frame_id: int, now: float) -> None:
        if frame_id == SENSORS:
            self.node, self.since = "ecu", now
        elif frame_id == ACTUATOR:
            self.node, self.since = "plant", now
        elif self._of.get(frame_id) == self.node:
            self.since = now

    def dead(self, now: float) -> str | None:
        return self.watch.check(self.node, self.since, now)


def _peer_lost(state: RunState, bus: RunBus) -> None:
    """A node is dead: the others are told (they run on their own clocks from now on, and
    show their reaction to the loss), and the command node's bus stops holding the run to its
    lockstep sequence."""
    for proc in state.children.values():
        if proc.poll() is None:
            try:
                proc.send_signal(PEER_LOST_SIGNAL)
            except ProcessLookupError:
                pass
    bus.relax()


class _Ending:
    """How a run that ends short of its last tick says so: which node ended it, when (the ticks
    the ECU had answered, as simulated time, and the wall time since tick 0) and why (its exit
    code and the last line it wrote, or the watch's verdict), in the abort reason and in the
    summary's ``ended_early``."""

    def __init__(self, state: RunState, command: CommandNode, period: float, logs: Path) -> None:
        self.state, self.command, self.period, self.logs = state, command, period, logs

    def end(self, node: str, why: str, *, code: int | None = None) -> None:
        state, tick = self.state, self.command.recorder.tick
        wall = time.perf_counter() - state.nodes_up if state.nodes_up is not None else 0.0
        said = _last_line(self.logs / f"{node}.log") if code is not None and code > 0 else ""
        state.status = "aborted"
        state.abort_reason = (
            f"{why}, at tick {tick} of {self.command.last_tick + 1} ({tick * self.period:.2f} s "
            f"simulated, {wall:.1f} s after tick 0)" + (f"; its last line: {said}" if said else "")
        )
        state.ended_early = {
            "node": node,
            "tick": tick,
            "time_s": tick * self.period,
            "wall_s": wall,
            "why": why,
            **({"exit_code": code} if code is not None else {}),
            **({"last_line": said} if said else {}),
        }


def _short_of_ticks(ending: _Ending, last: float | None, start: float, period: float) -> None:
    """Real time: the run's clock ran out before the ECU answered every tick. Said with when its
    answers stopped, or how far behind the run's clock they fell."""
    command = ending.command
    answered, total = command.recorder.tick, command.last_tick + 1
    now = time.monotonic()
    said = f"the ECU answered {answered} of {total} ticks by the end of the run's clock"
    if last is None:
        why = f"{said}: none came"
    elif now - last > STOPPED_ANSWERS_S:
        why = f"{said}: its answers stopped {now - last:.1f} s before it ended"
    else:
        rate = answered / max(last - start, period)
        why = (
            f"{said}: it fell {total - answered} ticks behind (its answers came at {rate:.1f} Hz, "
            f"the run's rate is {1.0 / period:g} Hz)"
        )
    ending.end("ecu", why)


def _exit(name: str, code: int) -> str:
    """How a node process ended: its exit code, and the signal that killed it."""
    try:
        by = f" (killed by {signal.Signals(-code).name})" if code < 0 else ""
    except ValueError:
        by = ""
    return f"{name} process exited with code {code}{by}"


def _node_exited(
    state: RunState, ending: _Ending, now: float, left: int | None = None
) -> float | None:
    """``now`` if a node process has exited, else None. One that failed marks the run aborted;
    one that ended cleanly (code 0: its last tick done) does not yet: the command node, behind
    it on a loaded machine, may still have its last frames to read (``_ended_early``). In real
    time (``left``: the ticks left on the run's clock) one that ended cleanly more than
    CLEAN_END_TICKS before the run's last tick aborts it too."""
    for name, proc in state.children.items():
        code = proc.poll()
        if code is not None:
            if code != 0:
                ending.end(name, f"{_exit(name, code)} mid-run", code=code)
            elif left is not None and left > CLEAN_END_TICKS:
                why = f"{name} process ended (code 0) {left} ticks before the run's last tick"
                ending.end(name, why, code=0)
            return now
    return None


def _ended_early(state: RunState, ending: _Ending) -> None:
    """The run aborts: a node that ended cleanly left it short of its last tick."""
    ended = [n for n, p in state.children.items() if p.poll() == 0] or ["a node"]
    why = (
        f"{ended[0]} process ended (code 0) before the ECU answered the run's last tick "
        f"(none came within {GRACE_S:g} s)"
    )
    ending.end(ended[0], why, code=0 if ended[0] in state.children else None)


def _silent(dog: Watchdog, seen: dict[int, float], state: RunState, now: float) -> str | None:
    """Why the run must end because a node fell silent, or None."""
    if state.ecu_heard is not None:  # through the bridge: what the ECU sent, before any fault
        # (only the ECU's IDs: the bridge may hear its own frames to the ECU's side)
        ecu = {i: at for i, at in dict(state.ecu_heard).items() if dog.node_of.get(i) == "ECU"}
        seen = {**seen, **{i: max(at, seen.get(i, at)) for i, at in ecu.items()}}
    return dog.silent(seen, now)
