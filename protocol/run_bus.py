"""A node's view of a bus shared by several runs: its own run's frames, with DBC IDs.

:class:`RunBus` wraps a python-can bus for the run of a tag (:mod:`protocol.run_tag`): it sends
each frame with the run's wire ID and hands on only the frames of its run, with their DBC IDs;
frames of other runs are dropped and counted (``foreign_frames``). The SimRun beacon (the
command node sends it with its run's RunId) is never handed on: a foreign one tells the runs
apart (``foreign_runs``), so a run that ended and a later one with the same tag count as two.

Within its own run's frames, a :class:`~protocol.run_sequence.RunSequence` given as ``sequence``
tells the run's frames from another sender's of the same IDs (a replay of a log onto the run's
bus, a device): those are dropped and counted too (``other_sender_frames``, per ID), and the
frames of a lockstep turn are held until the turn's last frame.

Where the bus names each frame's sender (the loopback bus, :mod:`protocol.udp_loopback`),
:meth:`RunBus.admit` makes the run's senders, once known, the only ones heard: a frame of any other
sender is dropped and counted as another sender's, whatever it carries, before any rule of the
sequence is asked; only the XCP transport's frames (a master's, the sequence's ``exempt``) are
heard from any sender. Elsewhere (SocketCAN, an adapter) a CAN frame carries no sender and the
sequence's rules are all there is (``sender`` is None).

It offers what the node drivers use (:mod:`protocol.node`: ``send_frame``, ``recv_frame``,
``recv_frames`` where the wrapped bus has them) and the plain ``send``/``recv`` of any bus.
"""

from __future__ import annotations

import struct
import time
from collections import Counter, deque
from collections.abc import Collection

import can

from protocol.dbc import xcp_frame_ids
from protocol.run_sequence import FIRST_KEPT, RunSequence
from protocol.run_tag import DBC_ID_MASK, split_id, wire_id

SIMRUN_ID = 2032  # the DBC's SimRun: RunId u32, RunTick u32, little-endian
_SIMRUN = struct.Struct("<II")

Frame = tuple[int, bytes] | can.Message


def simrun_payload(run_id: int, run_tick: int) -> bytes:
    """The SimRun beacon's data."""
    return _SIMRUN.pack(run_id & 0xFFFFFFFF, run_tick & 0xFFFFFFFF)


class RunBus(can.BusABC):
    """The frames of run ``tag`` on ``bus`` (which it owns: :meth:`shutdown` shuts it down)."""

    def __init__(self, bus: can.BusABC, tag: int = 0, sequence: RunSequence | None = None) -> None:
        try:
            wire_id(tag, 0)  # refuses a bad tag
        except ValueError:
            bus.shutdown()
            raise
        self.bus = bus
        self.tag = tag
        self.sequence = sequence
        self._ready: deque[Frame] = deque()  # frames released by the sequence, not yet taken
        self._relax = False  # relax() was asked for
        self.foreign_frames = 0  # other runs' frames (see stats for another sender's)
        self._foreign: dict[int, set[int]] = {}  # foreign tag -> RunIds of its beacons
        self.senders: frozenset[str] | None = None  # the run's senders, once admitted
        self._open: frozenset[int] = frozenset()  # ... and the IDs heard from any sender
        self._others: Counter[int] = Counter()  # without a sequence: other senders', per ID
        self._first_others: list[str] = []
        self._recv_frames = getattr(bus, "recv_frames", None)
        self.channel_info = f"run tag {tag} on {bus.channel_info}"
        super().__init__(channel=getattr(bus, "channel", None))
        if self._recv_frames is None:  # the drivers then read one frame at a time
            self.recv_frames = None  # type: ignore[method-assign,assignment]

    @property
    def foreign_runs(self) -> int:
        """Other runs heard: one per RunId of their beacons (one per tag without a beacon)."""
        return sum(max(1, len(ids)) for ids in self._foreign.values())

    @property
    def sender(self) -> str | None:
        """The token naming this node's frames on the bus, or None where frames carry no
        sender."""
        return getattr(self.bus, "token", None)

    def admit(self, senders: Collection[str]) -> bool:
        """Hear only the frames of ``senders`` (the run's, by their tokens) from now on, and the
        XCP transport's of any sender; False where the bus cannot tell senders apart."""
        admit = getattr(self.bus, "admit", None)
        if admit is None or self.sender is None:
            return False
        self.senders = frozenset(senders)
        if self.sequence is not None:
            self._open = self.sequence.exempt
        else:
            self._open = frozenset(xcp_frame_ids())
        admit(self.senders, self._other_sender)
        return True

    def hold(self, timeout: float) -> None:
        """Wait ``timeout`` seconds, holding what comes meanwhile where the bus can (heard later,
        once the run's senders are admitted), so that the node's queue does not overflow."""
        hold = getattr(self.bus, "hold", None)
        if hold is None:
            time.sleep(timeout)
        else:
            hold(timeout)

    def _other_sender(self, sender: str, got: Frame) -> bool:
        """A frame of a sender that is not the run's: heard if it is the XCP transport's, else
        counted as another sender's (another run's, by its tag, as such) and dropped."""
        if type(got) is not tuple and (got.is_error_frame or got.is_remote_frame or got.is_fd):
            return False
        own = self._own(got)
        if own is None:
            return False
        frame_id, data = own if type(own) is tuple else (own.arbitration_id, bytes(own.data))
        if frame_id in self._open:
            return True
        why = f"sent by {sender}, not a sender of the run"
        if self.sequence is not None:
            self.sequence.drop(frame_id, data, why)
            return False
        self._others[frame_id] += 1
        if len(self._first_others) < FIRST_KEPT:
            self._first_others.append(f"0x{frame_id:03X} {bytes(data).hex()}: {why}")
        return False

    def stats(self) -> dict:
        """``foreign_frames``: every frame dropped, other runs' and another sender's;
        ``foreign_runs``; another sender's frames alone, per ID (with a sequence, or once the
        run's senders are admitted)."""
        other = self.sequence.stats() if self.sequence is not None else self._other_stats()
        return {
            "run_tag": self.tag,
            "foreign_frames": self.foreign_frames + other.get("other_sender_frames", 0),
            "foreign_runs": self.foreign_runs,
            **other,
        }

    def _other_stats(self) -> dict:
        if self.senders is None:
            return {}
        return {
            "other_sender_frames": sum(self._others.values()),
            "other_sender_ids": {f"0x{i:03X}": n for i, n in sorted(self._others.items())},
            **({"other_sender_first": list(self._first_others)} if self._first_others else {}),
        }

    # -- sending --------------------------------------------------------------------------------
    def send_frame(self, frame_id: int, data: bytes | bytearray) -> None:
        if self.tag == 0 and (send_frame := getattr(self.bus, "send_frame", None)) is not None:
            send_frame(frame_id, data)
        else:
            wire, extended = wire_id(self.tag, frame_id)
            message = can.Message(arbitration_id=wire, data=bytes(data), is_extended_id=extended)
            self.bus.send(message)
        if self.sequence is not None:
            self._ready.extend(self.sequence.sent(frame_id))

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_extended_id or msg.is_error_frame:
            raise can.CanOperationError("a run sends only frames with DBC (standard) IDs")
        wire, extended = wire_id(self.tag, msg.arbitration_id)
        out = msg if not extended else _with_id(msg, wire, extended)
        self.bus.send(out, timeout)
        if self.sequence is not None:
            self._ready.extend(self.sequence.sent(msg.arbitration_id))

    # -- receiving ------------------------------------------------------------------------------
    def recv_frame(self, timeout: float | None) -> Frame | None:
        """The next frame of this run (as the wrapped bus's ``recv_frame`` or ``recv`` gives
        it, with its DBC ID), or None after ``timeout`` seconds (None: wait for ever)."""
        if self._relax:
            self._relaxed()
        if self._ready:
            return self._ready.popleft()
        receive = getattr(self.bus, "recv_frame", self.bus.recv)
        deadline = None if timeout is None else time.monotonic() + timeout
        while (got := receive(timeout)) is not None:
            own = self._own(got)
            if own is not None:
                if self.sequence is None:
                    return own
                self._ready.extend(self._checked(own))
                if self._ready:
                    return self._ready.popleft()
            if deadline is not None:
                timeout = max(0.0, deadline - time.monotonic())
        return None

    def recv_frames(self, timeout: float | None) -> list[Frame]:
        """Every frame of this run queued, as the wrapped bus's ``recv_frames`` gives them."""
        own = self._own
        frames = [f for got in self._recv_frames(timeout) if (f := own(got)) is not None]
        if self.sequence is None:
            return frames
        if self._relax:
            self._relaxed()
        out = list(self._ready)
        self._ready.clear()
        for frame in frames:
            out += self._checked(frame)
        return out

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._relax:
            self._relaxed()
        if self._ready:
            ready = self._ready.popleft()
            assert isinstance(ready, can.Message)
            return ready, False
        msg = self.bus.recv(timeout)
        if msg is None:
            return None, False
        own = self._own(msg)
        assert own is None or isinstance(own, can.Message)
        if own is None or self.sequence is None:
            return own, False
        self._ready.extend(self._checked(own))
        return (self._ready.popleft() if self._ready else None), False

    def relax(self) -> None:
        """The run's lockstep is over (:meth:`RunSequence.relax`): only another sender's frames
        of this node's own IDs are dropped from the next read on, and the frames held are
        handed on then (safe from a signal handler)."""
        self._relax = self.sequence is not None

    def _relaxed(self) -> None:
        assert self.sequence is not None
        self._relax = False
        self._ready.extend(self.sequence.relax())

    def _checked(self, frame: Frame) -> list[Frame]:
        """The frames the sequence hands on for one frame of this run (with its DBC ID); after
        a relax() asked for while frames were being read, the held frames first."""
        assert self.sequence is not None
        out: list[Frame] = []
        if self._relax:
            self._relax = False
            out = self.sequence.relax()
        if type(frame) is tuple:
            return out + self.sequence.heard(frame, frame[0], frame[1])
        if frame.is_error_frame or frame.is_remote_frame or frame.is_fd or frame.is_extended_id:
            return [*out, frame]  # of no run: the driver counts it (protocol.node)
        return out + self.sequence.heard(frame, frame.arbitration_id, frame.data)

    def _own(self, got: Frame) -> Frame | None:
        """The frame as this run's node sees it, or None (another run's, or a beacon)."""
        if type(got) is tuple:
            frame_id, data, extended = got[0], got[1], False
        else:
            if got.is_error_frame or got.is_remote_frame or got.is_fd:
                return got  # of no run: the driver counts it (protocol.node)
            frame_id, data, extended = got.arbitration_id, got.data, got.is_extended_id
        split = split_id(frame_id, extended)
        if split is None:  # an extended ID no run sends: the primary run's driver counts it
            if self.tag == 0:
                return got
            self.foreign_frames += 1
            return None
        tag, dbc_id = split
        if tag != self.tag:
            self.foreign_frames += 1
            runs = self._foreign.setdefault(tag, set())
            if dbc_id == SIMRUN_ID and len(data) == _SIMRUN.size:
                runs.add(_SIMRUN.unpack(bytes(data))[0])
            return None
        if dbc_id == SIMRUN_ID:
            return None
        if not extended:
            return got
        if type(got) is tuple:
            return dbc_id, data
        return _with_id(got, dbc_id, False)

    # -- filters and the rest -------------------------------------------------------------------
    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        """The wrapped bus lets through every run's frames of the IDs asked for (it checks the
        11 bits of the DBC ID, so that the other runs' frames are counted) and the beacons."""
        if not filters:
            self.bus.set_filters(None)
            return
        ids = {(f["can_id"] & DBC_ID_MASK, f["can_mask"] & DBC_ID_MASK) for f in filters}
        ids.add((SIMRUN_ID, DBC_ID_MASK))
        self.bus.set_filters([{"can_id": i, "can_mask": m} for i, m in sorted(ids)])

    def fileno(self) -> int:
        return self.bus.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self.bus.shutdown()


def _with_id(msg: can.Message, arbitration_id: int, extended: bool) -> can.Message:
    return can.Message(
        timestamp=msg.timestamp,
        arbitration_id=arbitration_id,
        is_extended_id=extended,
        dlc=msg.dlc,
        data=msg.data,
        channel=msg.channel,
        is_rx=msg.is_rx,
    )
