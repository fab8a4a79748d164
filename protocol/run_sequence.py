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

Frames that fail are dropped and counted per ID (:attr:`RunSequence.foreign`). The command node's
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
        self._held: list[tuple[object, int, bytes]] = []  # this turn's frames, as they came
        self._last: dict[int, bytes] = {}  # each message's last frame taken
        self._last_of_index: dict[tuple[int, int], bytes] = {}  # ... and per multiplexer index
        self.foreign: Counter[int] = Counter()  # frames of another sender, per ID
        self.ties = 0  # two frames of one message in a turn, told apart by their values

    def relax(self) -> list:
        """From now on only rule 1: the run's lockstep is over (a node was found dead, and its
        peer runs on its own clock). The frames held, to hand on."""
        self.strict = False
        held, self._held = self._held, []
        return [frame for frame, _, _ in held]

    # -- the node's own frames ------------------------------------------------------------------
    def sent(self, frame_id: int) -> None:
        """The node sent a frame: its own PlantSensors or EcuActuator moves the turn on."""
        m = self.messages.get(frame_id)
        if m is not None and m.ends_turn and m.role == self.turn:
            self._release()  # (a node hears no frames of its own turn: nothing is held)
            self._next_turn()

    # -- frames heard ---------------------------------------------------------------------------
    def heard(self, frame: object, frame_id: int, data: bytes | bytearray) -> list:
        """The frames to hand to the node now: ``frame`` (as the bus gave it, ``frame_id`` and
        ``data`` its DBC ID and payload) if it is the run's and is not held, with the turn's
        held frames when it ends the turn; none if it is foreign or held."""
        if frame_id in self.own_ids:
            self.foreign[frame_id] += 1
            return []
        if not self.strict or frame_id in self.exempt:
            return [frame]
        m = self.messages.get(frame_id)
        if m is None or len(data) != 8 or not self._fits(m, data):
            self.foreign[frame_id] += 1
            return []
        if m.role == COMMAND:
            self._take(m, data)
            return [frame]
        if not m.ends_turn:
            self._held.append((frame, frame_id, bytes(data)))
            return []
        out = self._release()
        self._take(m, data)
        out.append(frame)
        self._next_turn()
        return out

    def _fits(self, m: _Message, data: bytes | bytearray) -> bool:
        """Rules 2 and 3: the turn (plant and ECU frames), due, the next counter, the tick."""
        if m.role != COMMAND and (m.role != self.turn or self.tick % m.every):
            return False
        if data[1] & 0x0F != self._counter[m.frame_id]:
            return False
        if m.mux:
            last = self._last.get(m.frame_id)
            if m.mux_of(data) != (m.mux[0] if last is None else m.next_mux(last)):
                return False
        if m.tick_shift == NO_TICK:
            return True
        tick = (int.from_bytes(data, "little") >> m.tick_shift) & 0xFFFF
        if m.role == COMMAND:
            return tick == self.next_demand
        return tick == self.tick % TICK_MODULO

    def _take(self, m: _Message, data: bytes | bytearray) -> None:
        self._counter[m.frame_id] = (self._counter[m.frame_id] + 1) % COUNTER_MODULO
        self._last[m.frame_id] = bytes(data)
        if m.mux:
            self._last_of_index[m.frame_id, m.mux_of(data)] = bytes(data)
        if m.role == COMMAND and m.tick_shift != NO_TICK:
            self.next_demand = (self.next_demand + self.demand_every) % TICK_MODULO

    def _release(self) -> list:
        """Rule 4 on the turn's held frames: those taken, in the order they came."""
        held, self._held = self._held, []
        if not held:
            return []
        by_id: dict[int, list[int]] = {}
        for i, (_, frame_id, _) in enumerate(held):
            by_id.setdefault(frame_id, []).append(i)
        taken = set()
        for frame_id, positions in by_id.items():
            if len(positions) > 1:
                self.ties += 1
                self.foreign[frame_id] += len(positions) - 1
                best = self._nearest(frame_id, [held[i][2] for i in positions])
                positions = [positions[best]]
            taken.add(positions[0])
            self._take(self.messages[frame_id], held[positions[0]][2])
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
        """``other_sender_frames`` and, per ID, ``other_sender_ids``; ``ties``."""
        return {
            "other_sender_frames": self.foreign_frames,
            "other_sender_ids": {f"0x{i:03X}": n for i, n in sorted(self.foreign.items())},
            **({"other_sender_ties": self.ties} if self.ties else {}),
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
