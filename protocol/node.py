"""Nodes are written sans-IO; drivers connect them to a python-can bus.

A node (the plant, the ECU, the scenario's command node) is a class with these methods, and
sends frames only through the ``send(frame_id, data)`` callable it is handed (``data`` may be a
codec buffer that is reused after the call returns: the callee copies it):

    start(send)                       once, before any frame; the plant sends tick 0 here
    on_frame(frame_id, data, send)    every frame heard on the bus (its own are not echoed)
    on_timeout(send)                  lockstep only: nothing heard for the guard time (wall clock)
    on_period(send)                   real time only: once per period of the node's own clock
    finished: bool                    true when the node has nothing more to do
    timeout_s: float | None           optional: lockstep silence before on_timeout, instead of
                                      the driver's guard (a node whose peer fell silent sets it to
                                      its own period and so runs on its own clock until frames
                                      come back)
    frame_ids: Collection[int]        optional: the only frame IDs the node handles; the drivers
                                      set them as the bus's filters, so that frames of other IDs
                                      are dropped by the bus (in the kernel on SocketCAN and on the
                                      loopback multicast bus) and never wake the node

The same node runs over any python-can bus (:func:`run_lockstep`, :func:`run_realtime`) or, in one
process with no bus at all, through :class:`protocol.node.InProcessBus` (``sil run --mode inproc``).
Frames that the contract cannot carry (extended IDs, remote, error and CAN FD frames) are counted
in ``DriverStats`` and never reach a node; with ``frame_ids``, only those of the node's IDs are
heard, and counted.
"""

from __future__ import annotations

import ctypes
import gc
import os
import sys
import time
from collections import deque
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import can

SendFn = Callable[[int, bytes | bytearray], None]
ID_MASK = 0x1FFFFFFF  # every bit of a frame ID (standard or extended)
STOP_POLL_S = 0.05  # lockstep: the longest a driver waits without looking at should_stop()
Received = tuple[int, bytes] | can.Message  # a frame as a bus's receiver gives it


class Node(Protocol):
    finished: bool

    def start(self, send: SendFn) -> None: ...

    def on_frame(self, frame_id: int, data: bytes | bytearray, send: SendFn) -> None: ...

    def on_timeout(self, send: SendFn) -> None: ...

    def on_period(self, send: SendFn) -> None: ...


@dataclass
class DriverStats:
    received: int = 0
    sent: int = 0
    ignored: dict[str, int] = field(default_factory=dict)  # reason -> count
    timeouts: int = 0
    polls: int = 0  # lockstep: waits the node itself asked for while idle (no peer yet)
    periods: int = 0
    overruns: int = 0  # real time: periods that started later than one period after their time
    jitter_s: list[float] = field(default_factory=list)  # real time: lateness of each period
    scheduling: str = ""  # real time: the policy the process ran at (realtime_scheduling)

    def ignore(self, reason: str) -> None:
        self.ignored[reason] = self.ignored.get(reason, 0) + 1

    def summary(self) -> dict:
        """The figures as a JSON-ready dict; in real time with the periods' lateness (ms)."""
        out: dict = {
            "frames_received": self.received,
            "frames_sent": self.sent,
            "frames_ignored": dict(self.ignored),
            "guard_timeouts": self.timeouts,
            "idle_polls": self.polls,
        }
        if self.periods:
            late = sorted(self.jitter_s)
            out |= {
                "periods": self.periods,
                "overruns": self.overruns,
                "scheduling": self.scheduling,
                "jitter_ms": {
                    "p50": 1e3 * late[len(late) // 2],
                    "p99": 1e3 * late[min(len(late) - 1, (99 * len(late)) // 100)],
                    "max": 1e3 * late[-1],
                },
            }
        return out


def unusable(msg: can.Message) -> str | None:
    """Why a message cannot reach a node (None: it can)."""
    if msg.is_error_frame:
        return "error frame"
    if msg.is_fd:
        return "CAN FD frame"
    if msg.is_remote_frame:
        return "remote frame"
    if msg.is_extended_id:
        return "extended ID"
    return None


def bus_sender(bus: can.BusABC, stats: DriverStats) -> SendFn:
    """``send`` for a node on this bus: through ``bus.send_frame`` where the bus has it (the
    loopback bus, :mod:`protocol.udp_loopback`), else one ``can.Message`` per frame."""
    send_frame = getattr(bus, "send_frame", None) or _message_sender(bus)

    def send(frame_id: int, data: bytes | bytearray) -> None:
        send_frame(frame_id, data)
        stats.sent += 1

    return send


def _message_sender(bus: can.BusABC) -> SendFn:
    def send_frame(frame_id: int, data: bytes | bytearray) -> None:
        bus.send(can.Message(arbitration_id=frame_id, data=bytes(data), is_extended_id=False))

    return send_frame


def listen_for(node: Node, bus: can.BusABC) -> None:
    """Set the node's ``frame_ids`` (if it names them) as the bus's filters."""
    frame_ids: Collection[int] | None = getattr(node, "frame_ids", None)
    if frame_ids is not None:
        bus.set_filters([{"can_id": i, "can_mask": ID_MASK} for i in frame_ids])


def bus_receiver(bus: can.BusABC) -> Callable[[float | None], Received]:
    """``bus.recv_frame`` where the bus has it (classical standard data frames come as
    ``(frame_id, data)``, :mod:`protocol.udp_loopback`), else ``bus.recv``."""
    return getattr(bus, "recv_frame", bus.recv)


def bus_batch_receiver(bus: can.BusABC) -> Callable[[float | None], list[Received]]:
    """``bus.recv_frames`` where the bus has it (every frame queued, at one wake-up), else
    ``bus.recv`` as a list of at most one message."""
    recv_frames = getattr(bus, "recv_frames", None)
    if recv_frames is not None:
        return recv_frames

    def receive(timeout: float | None) -> list[Received]:
        msg = bus.recv(timeout)
        return [] if msg is None else [msg]

    return receive


def _deliver(node: Node, got: Received, send: SendFn, stats: DriverStats) -> None:
    """Hand a frame to the node, or count why it cannot be (``got`` is not None)."""
    if type(got) is tuple:
        frame_id, data = got
    else:
        reason = unusable(got)
        if reason is not None:
            stats.ignore(reason)
            return
        frame_id, data = got.arbitration_id, got.data
    stats.received += 1
    node.on_frame(frame_id, data, send)


FINAL_WAIT_S = 0.0015  # a real-time period's last stretch: a precise sleep, not a bus wait
SPIN_S = 0.0001  # ... and its last 100 us a spin on the clock
_PR_SET_TIMERSLACK = 29
TIMER_SLACK_NS = 1000


def realtime_scheduling(priority: int = 10) -> str:
    """The best scheduling this process may have for real-time pacing, and its name: SCHED_FIFO
    at ``priority`` where the user's rights allow it, else the normal policy; and (Linux) a timer
    slack of 1 us instead of the default 50 us, so that a sleep ends close to its deadline."""
    if sys.platform == "linux":
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_TIMERSLACK, TIMER_SLACK_NS, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f"SCHED_FIFO {priority}"
    except (AttributeError, PermissionError, OSError):
        return "normal"


def run_lockstep(
    node: Node,
    bus: can.BusABC,
    *,
    guard_s: float | Callable[[], float] = 1.0,
    should_stop: Callable[[], bool] = lambda: False,
) -> DriverStats:
    """Drive a node by the frames it hears; ``on_timeout`` after ``guard_s`` of silence (a
    callable: the guard as it is now, looked at again while the node waits, so that a launcher
    may shorten it)."""
    stats = DriverStats()
    send = bus_sender(bus, stats)
    receive = bus_receiver(bus)
    listen_for(node, bus)
    node.start(send)
    on_frame = node.on_frame
    guard = guard_s if callable(guard_s) else (lambda: guard_s)
    while not node.finished and not should_stop():
        timeout = getattr(node, "timeout_s", None)
        got = _receive_within(receive, timeout or guard, should_stop)
        if type(got) is tuple:  # the usual case, inline
            stats.received += 1
            on_frame(got[0], got[1], send)
        elif got is None:
            if should_stop():  # the wait was cut short: no timeout
                break
            if getattr(node, "polling", False):  # its idle poll, not a guard
                stats.polls += 1
            else:
                stats.timeouts += 1
            node.on_timeout(send)
        else:
            _deliver(node, got, send, stats)
    return stats


def _receive_within(
    receive: Callable[[float | None], Received],
    timeout: float | Callable[[], float],
    should_stop: Callable[[], bool],
) -> Received | None:
    """A frame within ``timeout`` seconds, or None. Waits of more than ``STOP_POLL_S`` go in
    slices of that, with ``should_stop()`` between them: a stop request (a signal handler
    setting a flag while the wait is in a system call, which Python then resumes) ends the
    wait within one slice, not the guard time. A callable ``timeout`` is looked at again after
    each slice."""
    limit = timeout if callable(timeout) else None
    first: float = limit() if limit is not None else timeout  # type: ignore[assignment]
    if first <= STOP_POLL_S:
        return receive(first)
    start = time.monotonic()
    deadline = start + first
    while (got := receive(STOP_POLL_S)) is None and not should_stop():
        if limit is not None:
            deadline = start + limit()
        left = deadline - time.monotonic()
        if left <= STOP_POLL_S:
            return receive(left) if left > 0 else None
    return got


def run_realtime(
    node: Node,
    bus: can.BusABC,
    period_s: float,
    *,
    should_stop: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> DriverStats:
    """Drive a node by its own wall clock: ``on_period`` every ``period_s``, frames in between.

    Periods are scheduled against absolute times from the start, so no drift accumulates. Until
    ``FINAL_WAIT_S`` before a period the node waits on the bus, taking frames as they come (bus
    waits are good to a millisecond); the last stretch is a sleep to the deadline (clock_nanosleep,
    good to tens of microseconds with the timer slack ``realtime_scheduling`` sets) and a spin
    on the clock for its last ``SPIN_S``. The period then starts (its lateness is measured here),
    takes the frames that came meanwhile, and runs. A period that starts more than
    one period late counts as an overrun and the missed ones are skipped, as a real-time
    scheduler would. Once the node is set up, every object then alive is frozen out of the
    cyclic collector (``gc.freeze``): its passes then walk only what the loop makes, not the
    hundreds of thousands of objects of the imports, whose full passes stalled a period for
    milliseconds (at 1 kHz, 30 s: about 130 overruns with them, 5 without).
    """
    stats = DriverStats()
    send = bus_sender(bus, stats)
    receive = bus_receiver(bus)
    listen_for(node, bus)
    node.start(send)
    gc.freeze()  # the set-up's objects: out of every later collection
    start = clock()
    k = 0
    while not node.finished and not should_stop():
        due = start + k * period_s
        now = clock()
        if now < due - FINAL_WAIT_S:
            got = receive(due - FINAL_WAIT_S - now)
            if got is not None:
                _deliver(node, got, send, stats)
            continue
        if now < due - SPIN_S:
            sleep(due - SPIN_S - now)
        while (now := clock()) < due:  # the last 100 us: a sleep's wake-up is not that exact
            pass
        lateness = now - due  # the period starts: it reads what came, then runs
        while (got := receive(0.0)) is not None:
            _deliver(node, got, send, stats)
        stats.jitter_s.append(lateness)
        if lateness > period_s:
            stats.overruns += 1
            k += int(lateness // period_s)
        node.on_period(send)
        stats.periods += 1
        k += 1
    return stats


class InProcessBus:
    """Several nodes in one process with no bus: a FIFO of frames delivered to every other node
    (that handles the frame's ID, when it names its ``frame_ids``).

    Deterministic by construction (frames are delivered in the order they were sent, to the nodes
    in their order), and the frames pass through the same codec as on a bus. ``tap`` sees every
    frame (the recorder).
    """

    def __init__(self, nodes: Sequence[Node], tap: Callable[[int, bytes], None] | None = None):
        self.nodes = list(nodes)
        self.tap = tap
        self._queue: deque[tuple[int, int, bytes]] = deque()
        self._senders = [self._sender(i) for i in range(len(self.nodes))]
        self._routes: dict[tuple[int, int], tuple[tuple[Callable, SendFn], ...]] = {}
        self.frames = 0

    def _sender(self, index: int) -> SendFn:
        def send(frame_id: int, data: bytes | bytearray) -> None:
            self._queue.append((index, frame_id, bytes(data)))

        return send

    def _route(self, origin: int, frame_id: int) -> tuple[tuple[Callable, SendFn], ...]:
        """(on_frame, send) of the nodes that hear a frame of this ID from node ``origin``."""
        route = tuple(
            (node.on_frame, send)
            for i, (node, send) in enumerate(zip(self.nodes, self._senders, strict=True))
            if i != origin and frame_id in getattr(node, "frame_ids", (frame_id,))
        )
        self._routes[origin, frame_id] = route
        return route

    def run(
        self,
        should_stop: Callable[[], bool] = lambda: False,
        done: Callable[[], bool] | None = None,
    ) -> None:
        """Start every node, then deliver frames until the queue is empty or ``done()``."""
        for node, send in zip(self.nodes, self._senders, strict=True):
            node.start(send)
        done = done or (lambda: all(n.finished for n in self.nodes))
        queue, routes, tap = self._queue, self._routes, self.tap
        while queue and not done() and not should_stop():
            origin, frame_id, data = queue.popleft()
            self.frames += 1
            if tap is not None:
                tap(frame_id, data)
            route = routes.get((origin, frame_id))
            if route is None:
                route = self._route(origin, frame_id)
            for on_frame, send in route:
                on_frame(frame_id, data, send)
