"""Which frames on a run's bus the run's own nodes sent: the rest are foreign.

A CAN frame carries no sender, and a run of tag 0 sends the DBC's IDs as they are, so a frame of
another sender of those IDs on the same bus (``sil replay LOG --bus`` of a recorded log, a device,
a test tool) looks like the run's own. In lockstep the run's traffic is one sequence, known to
every node of the run, and :class:`RunSequence` keeps a node to it (``strict``):

1. **Own IDs.** A node never hears its own frames (the buses do not echo them): a frame of an ID
   the node sends itself is another sender's.
2. **Turns.** The plant and the ECU take turns: the plant's frames of tick k (PlantTruthA/B/C,
   PlantAnalog when due, PlantSensors(k) last), then the ECU's (EcuStatus, EcuTelemetry,
   EcuStarter when due, EcuActuator(k) last). A plant frame in the ECU's turn, or an ECU frame in
   the plant's, is not the run's. The turn moves on at the run's PlantSensors(k) and
   EcuActuator(k), heard or sent by the node itself.
3. **Sequence.** Each message of the run has one sender, which starts its alive counter at 0 and
   loses no frame: a frame must carry the next counter of its message, the turn's tick
   (SensorTick, AnalogTick, ActuatorTick, StarterTick) or the next DemandTick, the next index of
   a multiplexed message (EcuTelemetry counts through its indexes from the first), and come at a
   tick where its message is due (its DBC cycle at the run's rate; PlantSensors, EcuActuator and
   EcuStarter at any tick).
4. **One per turn.** The frames of a turn are held until the turn's last frame (PlantSensors,
   EcuActuator), which is decided at once. A message with two frames that pass 1-3 in one turn
   (a tie, counted in ``ties``) has a second sender: the frame whose values are clearly nearer
   the message's previous frame (of the same multiplexer index) is taken, else the later one (the
   run's frames come in a burst just before the turn's last frame, another sender's anywhere in
   the turn); the other is foreign.

5. **Resync.** A frame of the run may be lost, or come after its turn's last frame (its sender
   moved between cores while sending a turn): its message's next frame then carries a counter
   (or multiplexer index) one further on. A frame that fits every rule but its place in its
   message's sequence is taken, and the sequence goes on from it, where its tick proves it
   (PlantSensors, PlantAnalog, EcuActuator, EcuStarter, Demand), or, for a message without a
   tick, where no frame of that message in sequence comes in the turn (the nearer by rule 4 if
   several do). A Demand after lost ones carries a tick and a counter both as many frames on
   (up to three). Counted in ``resyncs``. A FaultInject must carry the next counter.
6. **Early frames.** A third node (the command node, hearing both) may get a frame of the next
   turn before the last frame of this one: the multicast loopback hands a datagram to its
   listeners one by one, and the peer, woken by the first, may answer before the sender's core
   reaches the last (a virtual core stalled by its host). A plant or ECU frame out of its turn
   that is the next turn's next frame of its message (rules 2 and 3) is therefore kept (up to
   ``EARLY_MAX``), and handed on in the run's order when its turn comes; one of a message that
   was due in its sender's last turn and did not come there is that turn's, late; the rest are
   dropped. Should this turn's last frame have been lost (the peer's last frame of the next
   turn kept, and a last frame of the turn after come), the turn is closed without it (a
   resync).

Frames that fail are dropped and counted per ID (:attr:`RunSequence.foreign`), as are those the
bus itself names as another sender's (:meth:`RunSequence.drop`: on the loopback bus, a sender
that is not a node of the run, :mod:`protocol.run_bus`). The command node's
frames (Demand, FaultInject) are not turn-bound: they are checked by 1 and 3 and passed at once.
Frames of no message of the run (the XCP transport's, ``exempt``) pass unchecked; with
``strict``, frames of IDs outside the contract are foreign.

What no rule can tell: a frame of another sender that carries exactly what the run's next frame
of its message carries (the same tick and alive counter, in the same turn, before it) is taken,
and the run's own then counted foreign. A replay of a log reaches the run's tick at most once
(where the run overtakes it), so this is a rare frame, not a stream.

Without ``strict`` (real time, where the nodes run on their own clocks and may start in any
order, and runs with bus faults, where frames are lost, repeated and delayed by design) only
rule 1 applies.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass

from protocol.codec import Codec, MessageCodec
from protocol.dbc import is_xcp
from protocol.lockstep import TICK_MODULO, every_ticks

PLANT, ECU, COMMAND = "Plant", "ECU", "Command"
SENSORS_NAME, ACTUATOR_NAME, DEMAND_NAME = "PlantSensors", "EcuActuator", "Demand"
# sent at every tick (EcuStarter while the ECU starts or stops the engine), whatever the rate;
# the others at their DBC cycle (protocol.lockstep.every_ticks)
EVERY_TICK = frozenset((SENSORS_NAME, ACTUATOR_NAME, "EcuStarter"))
COUNTER_MODULO = 15
NO_TICK = -1
EARLY_MAX = 64  # rule 6: at most this many frames kept for the next turn
LOST_DEMANDS = 3  # rule 5: a Demand may follow this many lost ones
FIRST_KEPT = 5  # the first frames dropped are kept with the reason, for the run's summary


@dataclass(frozen=True)
class _Message:
    """What the rules need of one message of the run."""

    frame_id: int
    role: str  # PLANT, ECU or COMMAND
    every: int  # due every this many ticks (1: any tick)
    tick_shift: int  # where its tick field starts (NO_TICK: none checked)
    ends_turn: bool  # PlantSensors, EcuActuator
    codec: MessageCodec
    mux: tuple[int, ...] = ()  # a multiplexed message's indexes, in the order they are sent

    def next_mux(self, data: bytes) -> int:
        """The index the frame after ``data`` (a frame of this message) carries."""
        index = self.mux.index(self.mux_of(data)) if self.mux_of(data) in self.mux else -1
        return self.mux[(index + 1) % len(self.mux)]

    def mux_of(self, data: bytes | bytearray) -> int:
        start, mask, _, _, _ = self.codec.mux_layout.field
        return (int.from_bytes(data, "little") >> start) & mask


def _role(m: MessageCodec) -> str | None:
    for role in (PLANT, ECU, COMMAND):
        if role in m.senders:
            return role
    return None


def _tick_shift(m: MessageCodec) -> int:
    """Where the tick this message carries for the turn (or the next Demand) starts."""
    if m.name not in ("PlantSensors", "PlantAnalog", "EcuActuator", "EcuStarter", DEMAND_NAME):
        return NO_TICK
    tick = [s for s in m.signals if s.name.endswith("Tick")]
    assert len(tick) == 1 and tick[0].length == 16, m.name
    return tick[0].start


def sent_by(codec: Codec, role: str) -> frozenset[int]:
    """The IDs of the messages the run's node ``role`` (PLANT, ECU, COMMAND) sends."""
    return frozenset(m.frame_id for m in codec.messages if role in m.senders)


class RunSequence:
    """One node's check of the run's frames (the module docstring's rules). ``own_ids``: what
    the node sends; ``rate_hz``: the run's ECU rate; ``exempt``: IDs passed unchecked (default:
    the XCP transport's)."""

    def __init__(
        self,
        codec: Codec,
        rate_hz: float,
        own_ids: Collection[int],
        *,
        strict: bool = True,
        exempt: Collection[int] | None = None,
    ) -> None:
        self.strict = strict
        self.own_ids = frozenset(own_ids)
        if exempt is None:
            exempt = [m.frame_id for m in codec.database.messages if is_xcp(m)]
        self.exempt = frozenset(exempt) - self.own_ids
        self.messages: dict[int, _Message] = {}
        for m in codec.messages:
            role = _role(m)
            if role is None or not m.protected:
                continue  # (SimRun: the run bus's own)
            every = every_ticks(m.cycle_time_ms, rate_hz) if m.cycle_time_ms else 1
            if role == COMMAND or m.name in EVERY_TICK:
                every = 1  # (Demand: checked by its tick; FaultInject: only by its counter)
            ends = m.name in (SENSORS_NAME, ACTUATOR_NAME)
            mux = tuple(sorted(m.mux_signals)) if m.multiplexed else ()
            self.messages[m.frame_id] = _Message(
                m.frame_id, role, every, _tick_shift(m), ends, m, mux
            )
        self.demand_every = every_ticks(codec[DEMAND_NAME].cycle_time_ms, rate_hz)
        self.turn = PLANT  # the plant's turn of tick 0 comes first
        self.tick = 0
        self.next_demand = 0  # the DemandTick the command node sends next (16-bit)
        self._counter: dict[int, int] = dict.fromkeys(self.messages, 0)
        # this turn's frames, as they came, each with why it is out of sequence (None: it is not)
        self._held: list[tuple[object, int, bytes, str | None]] = []
        self._early: list[tuple[object, int, bytes]] = []  # the next turn's, come before its time
        self._last: dict[int, bytes] = {}  # each message's last frame taken
        self._taken_at: dict[int, int] = {}  # ... and the tick of its turn
        self._last_of_index: dict[tuple[int, int], bytes] = {}  # ... and per multiplexer index
        self.foreign: Counter[int] = Counter()  # frames of another sender, per ID
        self.first: list[str] = []  # the first few dropped, and why (FIRST_KEPT)
        self.ties = 0  # two frames of one message in a turn, told apart by their values
        self.resyncs = 0  # frames taken out of their message's sequence (rule 5)
        self.first_resyncs: list[str] = []

    def relax(self) -> list:
        """From now on only rule 1: the run's lockstep is over (a node was found dead, and its
        peer runs on its own clock). The frames held, to hand on."""
        self.strict = False
        held, self._held = self._held, []
        early, self._early = self._early, []
        return [frame for frame, _, _, _ in held] + [frame for frame, _, _ in early]

    # -- the node's own frames ------------------------------------------------------------------
    def sent(self, frame_id: int) -> list:
        """The node sent a frame: its own PlantSensors or EcuActuator moves the turn on. The
        frames to hand to the node now (its peer's that came early, none in lockstep)."""
        m = self.messages.get(frame_id)
        if m is None or not m.ends_turn or not self.strict:  # (without strict: no turns)
            return []
        if m.role != self.turn:  # its peer's last frame was lost: past that turn first
            self._skip_turn()
        self._release()  # (a node hears no frames of its own turn: nothing is held)
        self._next_turn()
        return self._replay_early()

    # -- frames heard ---------------------------------------------------------------------------
    def heard(self, frame: object, frame_id: int, data: bytes | bytearray) -> list:
        """The frames to hand to the node now: ``frame`` (as the bus gave it, ``frame_id`` and
        ``data`` its DBC ID and payload) if it is the run's and is not held, with the turn's
        held frames when it ends the turn; none if it is foreign or held."""
        if frame_id in self.own_ids:
            self.drop(frame_id, data, "an ID this node sends")
            return []
        if not self.strict or frame_id in self.exempt:
            return [frame]
        m = self.messages.get(frame_id)
        if m is None:
            self.drop(frame_id, data, "no message of the run")
            return []
        if m.role != COMMAND and m.role != self.turn:
            return self._come_early(m, frame, data)
        if self._early and self._lost_end(m, data):
            return self._skip_turn() + self.heard(frame, frame_id, data)
        why, in_step = self._misfit(m, data)
        # rule 5: out of its message's sequence is the run's still where its tick proves it, or
        # (held to the turn's end) where no frame of the message in sequence comes in the turn
        if why is not None and not (in_step and (m.tick_shift != NO_TICK or m.role != COMMAND)):
            self.drop(frame_id, data, why)
            return []
        if m.role == COMMAND or m.ends_turn:
            return self._end_turn(m, frame, data, why)
        self._held.append((frame, frame_id, bytes(data), why))
        return []

    def _end_turn(
        self, m: _Message, frame: object, data: bytes | bytearray, why: str | None
    ) -> list:
        """Take a Demand or FaultInject (not turn-bound), or the turn's last frame with the
        turn's held frames before it."""
        if m.role == COMMAND:
            self._take(m, data, why)
            return [frame]
        out = self._release()
        self._take(m, data, why)
        out.append(frame)
        self._next_turn()
        return out + self._replay_early()

    def _come_early(self, m: _Message, frame: object, data: bytes | bytearray) -> list:
        """Rule 6: a plant or ECU frame out of its turn. One of a message that was due in its
        sender's last turn and did not come is that turn's, late: dropped. Else, if it is the
        next turn's next frame of its message (rules 2 and 3), it is kept for that turn (up to
        ``EARLY_MAX``), else dropped."""
        last = self.tick - (m.role == ECU)  # the tick of its sender's last turn
        if last >= 0 and last % m.every == 0 and self._taken_at.get(m.frame_id) != last:
            self.drop(m.frame_id, data, f"after the {m.role}'s turn of tick {last} ended")
            return []  # (due then, and none came: it is that turn's, late)
        why, _ = self._misfit(m, data, (m.role, last + 1))  # checked as the next turn's, now
        if why is not None or len(self._early) >= EARLY_MAX:
            self.drop(m.frame_id, data, f"before its turn: {why or 'too many before it'}")
            return []
        self._early.append((frame, m.frame_id, bytes(data)))
        return []

    def _lost_end(self, m: _Message, data: bytes | bytearray) -> bool:
        """This turn's last frame was lost: ``m`` is a last frame of this turn's sender carrying
        the tick of its next turn, and its peer's last frame of the turn between is kept."""
        if not m.ends_turn or not any(self.messages[f].ends_turn for _, f, _ in self._early):
            return False
        tick = (int.from_bytes(data, "little") >> m.tick_shift) & 0xFFFF
        return tick == (self.tick + 1) % TICK_MODULO

    def _skip_turn(self) -> list:
        """This turn's last frame was lost: its held frames, then the next turn's that came."""
        self.resyncs += 1
        if len(self.first_resyncs) < FIRST_KEPT:
            self.first_resyncs.append(f"the {self.turn}'s turn of tick {self.tick}: no last frame")
        out = self._release()
        self._next_turn()
        return out + self._replay_early()

    def _replay_early(self) -> list:
        """The frames that came before their turn, heard again now that it has come."""
        early, self._early = self._early, []
        out: list = []
        for frame, frame_id, data in early:
            out += self.heard(frame, frame_id, data)
        return out

    def _misfit(
        self, m: _Message, data: bytes | bytearray, turn: tuple[str, int] | None = None
    ) -> tuple[str | None, bool]:
        """Rules 2 and 3: why the frame is not the run's next of its message (None: it is), and
        whether it fits but for its place in the message's sequence (the alive counter or the
        multiplexer index: a frame of the run was lost or came late). ``turn``: the sender and
        tick of the turn to check it against (default: this one)."""
        role, at = turn or (self.turn, self.tick)
        if len(data) != 8:
            return f"{len(data)} bytes", False
        if m.role != COMMAND and m.role != role:
            return f"in the {role}'s turn", False
        if m.role != COMMAND and at % m.every:
            return f"not due (every {m.every} ticks)", False
        if m.tick_shift != NO_TICK:
            tick = (int.from_bytes(data, "little") >> m.tick_shift) & 0xFFFF
            expected = self.next_demand if m.role == COMMAND else at % TICK_MODULO
            if tick != expected:
                lost = self._demands_lost(m, data, tick)
                return f"tick {tick}, the run's is {expected}", lost
        if (counter := data[1] & 0x0F) != self._counter[m.frame_id]:
            return f"alive counter {counter}, the run's next is {self._counter[m.frame_id]}", True
        if m.mux:
            last = self._last.get(m.frame_id)
            index = m.mux[0] if last is None else m.next_mux(last)
            if m.mux_of(data) != index:
                return f"index {m.mux_of(data)}, the run's next is {index}", True
        return None, False

    def _demands_lost(self, m: _Message, data: bytes | bytearray, tick: int) -> bool:
        """A Demand whose tick and alive counter are both j frames on from the run's next (j up
        to LOST_DEMANDS): the j before it were lost."""
        if m.role != COMMAND:
            return False
        ahead = (tick - self.next_demand) % TICK_MODULO
        j = ahead // self.demand_every
        counter = (self._counter[m.frame_id] + j) % COUNTER_MODULO
        return (
            ahead % self.demand_every == 0 and 1 <= j <= LOST_DEMANDS and data[1] & 0x0F == counter
        )

    def drop(self, frame_id: int, data: bytes | bytearray, why: str) -> None:
        """A frame of another sender: counted, and kept with ``why`` if among the first."""
        self.foreign[frame_id] += 1
        if len(self.first) < FIRST_KEPT:
            self.first.append(f"0x{frame_id:03X} {bytes(data).hex()} at tick {self.tick}: {why}")

    def _take(self, m: _Message, data: bytes | bytearray, why: str | None = None) -> None:
        """The run's next frame of ``m``; ``why``: it is out of the message's sequence (rule 5),
        which goes on from it."""
        if why is not None:
            self.resyncs += 1
            if len(self.first_resyncs) < FIRST_KEPT:
                self.first_resyncs.append(
                    f"0x{m.frame_id:03X} {bytes(data).hex()} at tick {self.tick}: {why}"
                )
        self._counter[m.frame_id] = ((data[1] & 0x0F) + 1) % COUNTER_MODULO
        self._taken_at[m.frame_id] = self.tick
        self._last[m.frame_id] = bytes(data)
        if m.mux:
            self._last_of_index[m.frame_id, m.mux_of(data)] = bytes(data)
        if m.role == COMMAND and m.tick_shift != NO_TICK:
            tick = (int.from_bytes(data, "little") >> m.tick_shift) & 0xFFFF
            self.next_demand = (tick + self.demand_every) % TICK_MODULO

    def _release(self) -> list:
        """Rules 4 and 5 on the turn's held frames: those taken, in the order they came."""
        held, self._held = self._held, []
        if not held:
            return []
        by_id: dict[int, list[int]] = {}
        for i, (_, frame_id, _, _) in enumerate(held):
            by_id.setdefault(frame_id, []).append(i)
        taken = set()
        for frame_id, positions in by_id.items():
            in_sequence = [i for i in positions if held[i][3] is None]
            candidates = in_sequence or positions  # (rule 5: only when none is in sequence)
            for i in positions:
                if held[i][3] is not None and in_sequence:
                    self.drop(frame_id, held[i][2], held[i][3])
            if len(candidates) > 1:
                self.ties += 1
                best = self._nearest(frame_id, [held[i][2] for i in candidates])
                for i in candidates[:best] + candidates[best + 1 :]:
                    self.drop(frame_id, held[i][2], "a second frame of its message in the turn")
                candidates = [candidates[best]]
            taken.add(candidates[0])
            self._take(self.messages[frame_id], held[candidates[0]][2], held[candidates[0]][3])
        return [held[i][0] for i in sorted(taken)]

    def _nearest(self, frame_id: int, candidates: list[bytes]) -> int:
        """The candidate whose values are nearest the message's previous frame (of the same
        multiplexer index: the same signal), each signal's change as a share of its range; a
        tie, or no previous frame: the last."""
        m = self.messages[frame_id]
        if m.mux:  # (the candidates carry the same index: rule 3)
            previous = self._last_of_index.get((frame_id, m.mux_of(candidates[0])))
        else:
            previous = self._last.get(frame_id)
        if previous is None:
            return len(candidates) - 1
        codec = m.codec
        before = _raw(codec, previous)
        scores = [_distance(codec, before, _raw(codec, c)) for c in candidates]
        last = len(candidates) - 1
        best = min(range(len(scores)), key=lambda i: (scores[i], -i))
        # the values decide only when they clearly do; else the later frame, which came in the
        # run's burst before the turn's last frame (another sender's comes anywhere in the turn)
        others = [s for i, s in enumerate(scores) if i != best]
        return best if all(scores[best] * 2 < s for s in others) else last

    def _next_turn(self) -> None:
        if self.turn == PLANT:
            self.turn = ECU
        else:
            self.turn = PLANT
            self.tick += 1

    # -- figures --------------------------------------------------------------------------------
    @property
    def foreign_frames(self) -> int:
        return sum(self.foreign.values())

    def stats(self) -> dict:
        """``other_sender_frames``, per ID ``other_sender_ids``, the first few dropped and why;
        ``ties``; ``sequence_resyncs`` (rule 5) and the first few."""
        return {
            "other_sender_frames": self.foreign_frames,
            "other_sender_ids": {f"0x{i:03X}": n for i, n in sorted(self.foreign.items())},
            **({"other_sender_ties": self.ties} if self.ties else {}),
            **({"other_sender_first": list(self.first)} if self.first else {}),
            **({"sequence_resyncs": self.resyncs} if self.resyncs else {}),
            **({"sequence_resyncs_first": list(self.first_resyncs)} if self.resyncs else {}),
        }


def _raw(codec: MessageCodec, data: bytes) -> list[int]:
    out = [0] * len(codec.signal_names)
    try:
        codec.unpack_raw(data, out)
    except (ValueError, KeyError, IndexError):  # (a mux index of no signal)
        pass
    return out


def _distance(codec: MessageCodec, a: list[int], b: list[int]) -> float:
    spans = [max(1, s.raw_max - s.raw_min) for s in codec.signals]
    if codec.multiplexed:
        spans.append(max(1, max(s.raw_max - s.raw_min for s in codec.mux_signals.values())))
    return sum(abs(x - y) / span for x, y, span in zip(a, b, spans, strict=False))
