"""The plant as a CAN node: a thin sans-IO layer between the protocol codec and ``Plant.step``.

Follows :mod:`protocol.lockstep`. At tick k the node sends the frames due at k (PlantTruthA/B,
PlantAnalog), then PlantSensors with SensorTick = k, last. Then:

- lockstep: it waits for EcuActuator with ActuatorTick = k and only then advances the plant one
  ECU period with that command (k += 1). Actuator frames for other ticks are counted (late or
  repeated, ahead) and do not advance time. If the driver's wall-clock guard passes first
  (``on_timeout``: a dead or slow ECU), the tick runs with the last command held;
- real time: one period per tick of the node's own clock (``on_period``), with whatever
  actuator command arrived last.

Either way, after ``watchdog_ticks`` ticks in a row without a valid actuator frame the pump
driver's watchdog removes pump power, as a real one would; a valid frame restores it.
FaultInject frames schedule faults at their FaultTick (at once when that tick has passed);
a fault the plant cannot represent, or a value out of range, is counted and ignored.
The node reuses its buffers: nothing it keeps grows per frame or per tick. With a plant of
plant/periphery.py the frames of a tick are packed by one compiled call (``pack_plant_frames``:
the codec's layout, saturation, alive counters and E2E CRC, from the plant's state array), which
gives the bytes the codec's ``pack_raw`` gives; any other plant goes through the codec.
"""

from __future__ import annotations

import copy

import numpy as np
from numba import njit

from plant import flags as fl
from plant.aerothermal import aero_period
from plant.fast_plant import fast_period
from plant.faults import Fault, FaultKind
from plant.interface import Plant
from plant.jit import EXACT
from plant.periphery import OUT, PlantBase
from protocol.codec import Codec, MessageCodec
from protocol.e2e import COUNTER_MODULO, E2EStatus, crc8
from protocol.lockstep import TICK_MODULO, every_ticks
from protocol.node import SendFn

# DBC VAL_ FaultTarget -> what it does (0 = CLEAR_ALL is handled apart)
FAULT_TARGETS: dict[int, FaultKind] = {
    1: FaultKind.PUMP_EFFECTIVENESS,
    2: FaultKind.PUMP_WEAR,
    3: FaultKind.COMPRESSOR_EFFICIENCY,
    4: FaultKind.COMPRESSOR_FLOW,
    5: FaultKind.TURBINE_EFFICIENCY,
    6: FaultKind.TURBINE_FLOW,
    7: FaultKind.SPEED_DROPOUT,
    8: FaultKind.SPEED_STUCK,
    9: FaultKind.SPEED_NOISE_BURST,
    10: FaultKind.EGT_OPEN_CIRCUIT,
    11: FaultKind.BATTERY_VOLTAGE,
    12: FaultKind.AMBIENT_TEMPERATURE,
}
SWITCHED = (
    FaultKind.SPEED_DROPOUT,
    FaultKind.SPEED_STUCK,
    FaultKind.EGT_OPEN_CIRCUIT,
)  # 1 on, 0 off
ENDED_BY_ZERO = (FaultKind.SPEED_NOISE_BURST, FaultKind.PUMP_WEAR)
CLEAR_ALL = 0
DEFAULT_WATCHDOG_TICKS = 10


def _clamp(x: int, lo: int, hi: int) -> int:
    return lo if x < lo else hi if x > hi else x


# ---- compiled packing of the plant's frames ---------------------------------------------------
# messages in the order they go out at a tick; their payloads are 8 bytes each of one buffer
FRAMES = ("PlantTruthA", "PlantTruthB", "PlantAnalog", "PlantSensors")
DUE_TRUTH, DUE_ANALOG = 1, 2
MAX_FIELDS = 8
# the int64 layout array: the CRC-8 table, then per message its alive counter, the CRC register
# after its data ID, its number of fields and (start, mask, raw_min, raw_max) per field
CRC_TABLE = 0
MESSAGE = 256
MESSAGE_SLOTS = 3 + 4 * MAX_FIELDS
COUNTER, CRC_START, N_FIELDS, FIELDS = range(4)
_O_TIME, _O_SPEED, _O_EGT, _O_SUPPLY, _O_CURRENT, _O_N_RPM = range(OUT, OUT + 6)
_O_P3, _O_P5, _O_T4, _O_FUEL, _O_THRUST = OUT + 7, OUT + 8, OUT + 9, OUT + 11, OUT + 13
_CLAMPED = fl.COMPRESSOR_MAP_CLAMPED | fl.TURBINE_MAP_CLAMPED | fl.PUMP_MAP_CLAMPED


def frame_layout(messages: list[MessageCodec]) -> np.ndarray:
    """The int64 layout array of ``pack_plant_frames`` for these messages (counters as now)."""
    lay = np.zeros(MESSAGE + MESSAGE_SLOTS * len(messages), dtype=np.int64)
    lay[CRC_TABLE : CRC_TABLE + 256] = [crc8(bytes((i,)), 0) for i in range(256)]
    for k, m in enumerate(messages):
        if not m.protected or m.multiplexed or len(m._fields) > MAX_FIELDS:
            raise ValueError(f"{m.name}: not a plain E2E-protected message")
        b = MESSAGE + MESSAGE_SLOTS * k
        lay[b + COUNTER], lay[b + CRC_START], lay[b + N_FIELDS] = (
            m.counter,
            m._crc_start,
            len(m._fields),
        )
        for i, (start, mask, _sign, raw_min, raw_max) in enumerate(m._fields):
            lay[b + FIELDS + 4 * i : b + FIELDS + 4 * i + 4] = (start, mask, raw_min, raw_max)
    return lay


@njit(**EXACT, inline="always")
def _field(lay: np.ndarray, b: int, i: int, raw: int) -> int:
    """One raw value saturated to its range and shifted into place (MessageCodec.pack_raw)."""
    f = b + FIELDS + 4 * i
    if raw < lay[f + 2]:
        raw = lay[f + 2]
    elif raw > lay[f + 3]:
        raw = lay[f + 3]
    return (raw & lay[f + 1]) << lay[f]


@njit(**EXACT, inline="always")
def _rounded(lay: np.ndarray, b: int, i: int, value: float) -> int:
    """round(value) (half to even) saturated to field i's range, shifted into place."""
    f = b + FIELDS + 4 * i
    r = np.rint(value)
    if r < lay[f + 2]:
        raw = lay[f + 2]
    elif r > lay[f + 3]:
        raw = lay[f + 3]
    else:
        raw = int(r)
    return (raw & lay[f + 1]) << lay[f]


@njit(**EXACT, inline="always")
def _finish(lay: np.ndarray, k: int, word: int, buf: np.ndarray) -> None:
    """Alive counter, little-endian bytes and CRC of message k into buf[8k:8k+8]."""
    b = MESSAGE + MESSAGE_SLOTS * k
    counter = lay[b + COUNTER]
    word |= counter << 8
    lay[b + COUNTER] = counter + 1 if counter < COUNTER_MODULO - 1 else 0
    at = 8 * k
    crc = lay[b + CRC_START]
    for i in range(1, 8):
        byte = (word >> (8 * i)) & 0xFF
        buf[at + i] = byte
        crc = lay[CRC_TABLE + (crc ^ byte)]
    buf[at] = crc


@njit(**EXACT)
def pack_plant_frames(
    s: np.ndarray, lay: np.ndarray, buf: np.ndarray, flags: int, tick16: int, due: int
) -> None:
    """Pack the frames due at this tick (FRAMES order; PlantSensors always) from the plant's
    outputs in its state array s, as PlantNode packs them through the codec."""
    if due & DUE_TRUTH:
        b = MESSAGE
        word = _field(lay, b, 0, 1 if flags & fl.FLAMEOUT else 0)
        word |= _field(lay, b, 1, 1 if flags & _CLAMPED else 0)
        word |= _field(lay, b, 2, 1 if flags & fl.OVERSPEED else 0)
        word |= _field(lay, b, 3, 1 if flags & fl.OVERTEMPERATURE else 0)
        word |= _rounded(lay, b, 4, s[_O_P3] * 0.1)
        word |= _rounded(lay, b, 5, s[_O_P5] * 0.1)
        word |= _rounded(lay, b, 6, s[_O_T4] * 10.0)
        _finish(lay, 0, word, buf)
        b = MESSAGE + MESSAGE_SLOTS
        word = _rounded(lay, b, 0, s[_O_FUEL] * 1e6)
        word |= _rounded(lay, b, 1, s[_O_THRUST] * 20.0)
        word |= _rounded(lay, b, 2, s[_O_N_RPM])
        _finish(lay, 1, word, buf)
    if due & DUE_ANALOG:
        b = MESSAGE + 2 * MESSAGE_SLOTS
        word = _field(lay, b, 0, tick16)
        word |= _rounded(lay, b, 1, s[_O_SUPPLY] * 1000.0)
        word |= _rounded(lay, b, 2, s[_O_CURRENT] * 1000.0)
        _finish(lay, 2, word, buf)
    b = MESSAGE + 3 * MESSAGE_SLOTS
    word = _field(lay, b, 0, tick16)
    word |= _rounded(lay, b, 1, s[_O_SPEED])
    word |= _rounded(lay, b, 2, s[_O_EGT] * 10.0)
    _finish(lay, 3, word, buf)


# ---- the lockstep node compiled, for a run in one compiled loop (sil/compiled_loop.py) ---------
# PlantNode's lockstep handling of EcuActuator and its advance, operation for operation, on an
# int64 state array (the NS_ slots) and a float64 one (NF_): the Python parts of a period (faults
# falling due, noise blocks) stay in Python (PlantNode.python_part), which the caller runs when
# ``python_due`` says so. PlantNode.compiled_state() and take_compiled_state() move the node's
# and its plant's state in and out.
(
    NS_TICK,  # PlantNode.tick
    NS_PLANT_TICK,  # the plant's ticks stepped (PlantBase._tick)
    NS_NOISE_LEFT,  # samples left in the noise blocks (PlantBase._noise_left)
    NS_FAULT_TICK,  # the earliest tick of the faults the node holds (pending), else NO_TICK
    NS_FLAGS,  # the plant's flags after its last period (plant.outputs.flags)
    NS_FRESH,
    NS_MISSED,
    NS_WATCHDOG,  # watchdog_ticks
    NS_TRIPS,  # watchdog_trips
    NS_PUMP_ENABLED,
    NS_REJECTED,  # actuator_rejected
    NS_LATE,  # actuator_late
    NS_AHEAD,  # actuator_ahead
    NS_MAX_TICKS,  # max_ticks, or -1
    NS_FINISHED,
    NS_EVERY_TRUTH,
    NS_EVERY_ANALOG,
    NS_KERNEL,  # index of the plant's kernel in KERNELS
    NS_CHECK_LAST,  # the actuator checker's last accepted counter (-1: none)
    NS_CHECK_STATUS,  # its last status
    NS_CHECK_CRC,  # its CRC register after the data ID
) = range(21)
NS_CHECK_COUNTS = 21  # its counts per E2EStatus
NS_FIELDS = NS_CHECK_COUNTS + len(E2EStatus)  # (start, mask, sign bit) per EcuActuator field
NS_SIZE = NS_FIELDS + 3 * 5
NF_DUTY, NF_FAULT_NEXT_S, NF_PERIOD, NF_SIZE = 0, 1, 2, 3
NO_TICK = 1 << 62
KERNELS = (aero_period, fast_period)  # the plants' compiled periods, by NS_KERNEL
_OK, _WRONGCRC, _REPEATED, _WRONGSEQUENCE = (
    int(E2EStatus.OK),
    int(E2EStatus.WRONGCRC),
    int(E2EStatus.REPEATED),
    int(E2EStatus.WRONGSEQUENCE),
)
_ACTUATOR_MAX_DELTA = 2  # PlantNode.actuator_check


@njit(**EXACT, inline="always")
def _actuator_check(ns: np.ndarray, lay: np.ndarray, data: np.ndarray) -> int:
    """E2EChecker.check of the node's actuator checker."""
    crc = ns[NS_CHECK_CRC]
    for i in range(1, 8):
        crc = lay[CRC_TABLE + (crc ^ data[i])]
    counter = data[1] & 0x0F
    if counter >= COUNTER_MODULO or crc != data[0]:
        status = _WRONGCRC
    else:
        last = ns[NS_CHECK_LAST]
        if last < 0:
            status = _OK
        else:
            delta = (counter - last) % COUNTER_MODULO
            if delta == 0:
                status = _REPEATED
            elif delta <= _ACTUATOR_MAX_DELTA:
                status = _OK
            else:
                status = _WRONGSEQUENCE
        if status != _REPEATED:
            ns[NS_CHECK_LAST] = counter
    ns[NS_CHECK_STATUS] = status
    ns[NS_CHECK_COUNTS + status] += 1
    return status


@njit(**EXACT, inline="always")
def _raw(ns: np.ndarray, word: int, i: int) -> int:
    """Field i of EcuActuator from the frame's 64-bit word (MessageCodec.unpack_raw)."""
    f = NS_FIELDS + 3 * i
    raw = (word >> ns[f]) & ns[f + 1]
    sign = ns[f + 2]
    return raw - (sign << 1) if sign and raw & sign else raw


@njit(**EXACT)
def actuator_compiled(ns: np.ndarray, nf: np.ndarray, lay: np.ndarray, data: np.ndarray) -> bool:
    """PlantNode._on_actuator in lockstep, to the advance: True when ``data`` (uint8[8]) answers
    this tick (the command taken and the watchdog counted, as _advance begins); the period
    itself is advance_compiled, after PlantNode.python_part when python_due."""
    if _actuator_check(ns, lay, data) != _OK:
        ns[NS_REJECTED] += 1
        return False
    word = 0
    for i in range(8):
        word |= np.int64(data[i]) << (8 * i)
    behind = (ns[NS_TICK] - _raw(ns, word, 2)) % TICK_MODULO
    if behind != 0:
        if behind < TICK_MODULO // 2:
            ns[NS_LATE] += 1
        else:
            ns[NS_AHEAD] += 1
        return False
    ns[NS_PUMP_ENABLED] = 1 if _raw(ns, word, 0) != 0 else 0  # _command
    duty = _raw(ns, word, 3)
    nf[NF_DUTY] = (0 if duty < 0 else 10000 if duty > 10000 else duty) * 1e-4
    ns[NS_MISSED] = 0  # _advance with a fresh command
    ns[NS_FRESH] = 0
    return True


@njit(**EXACT)
def python_due(ns: np.ndarray, nf: np.ndarray) -> bool:
    """Before the period: PlantNode.python_part has something to do (a fault the node holds
    falls due, the plant's fault schedule, the noise blocks run out)."""
    return (
        ns[NS_FAULT_TICK] <= ns[NS_TICK]
        or nf[NF_FAULT_NEXT_S] <= ns[NS_PLANT_TICK] * nf[NF_PERIOD] + 1e-9
        or ns[NS_NOISE_LEFT] == 0
    )


@njit(**EXACT)
def advance_compiled(
    s: np.ndarray, tables: np.ndarray, ns: np.ndarray, nf: np.ndarray, lay: np.ndarray,
    buf: np.ndarray,
) -> int:  # fmt: skip
    """The rest of PlantNode._advance: the plant's period (PlantBase._period_with) and the next
    tick's frames packed into buf (FRAMES order); returns which are due (DUE_ bits)."""
    powered = ns[NS_PUMP_ENABLED] != 0 and ns[NS_MISSED] <= ns[NS_WATCHDOG]
    u = nf[NF_DUTY] if powered else 0.0
    tick = ns[NS_PLANT_TICK] + 1
    if ns[NS_KERNEL] == 0:
        flags = aero_period(s, tables, u, powered, tick, True)
    else:
        flags = fast_period(s, tables, u, powered, tick, True)
    ns[NS_NOISE_LEFT] -= 1
    ns[NS_PLANT_TICK] = tick
    ns[NS_FLAGS] = flags
    k = ns[NS_TICK] + 1
    ns[NS_TICK] = k
    if ns[NS_MAX_TICKS] >= 0 and k >= ns[NS_MAX_TICKS]:
        ns[NS_FINISHED] = 1
    due = (DUE_TRUTH if k % ns[NS_EVERY_TRUTH] == 0 else 0) | (
        DUE_ANALOG if k % ns[NS_EVERY_ANALOG] == 0 else 0
    )
    pack_plant_frames(s, lay, buf, flags, k % TICK_MODULO, due)
    return due


class PlantNode:
    """A plant (AeroThermalPlant or FastPlant) on the bus; ``max_ticks`` makes the node finish
    after that many ECU periods (None: run until stopped)."""

    def __init__(
        self,
        plant: Plant,
        *,
        lockstep: bool = True,
        max_ticks: int | None = None,
        watchdog_ticks: int = DEFAULT_WATCHDOG_TICKS,
        codec: Codec | None = None,
    ) -> None:
        if watchdog_ticks < 1:
            raise ValueError(f"watchdog_ticks must be >= 1, got {watchdog_ticks!r}")
        # one step of a throwaway copy compiles whatever numba has not cached yet, now rather
        # than after tick 0 is on the bus, where a stall of seconds would look like a dead plant
        copy.deepcopy(plant).step(plant.trim_duty)
        self.plant = plant
        self.lockstep = lockstep
        self.max_ticks = max_ticks
        self.watchdog_ticks = watchdog_ticks
        codec = codec or Codec()
        self.sensors = codec["PlantSensors"]
        self.analog = codec["PlantAnalog"]
        self.truth_a = codec["PlantTruthA"]
        self.truth_b = codec["PlantTruthB"]
        self.actuator = codec["EcuActuator"]
        self.fault = codec["FaultInject"]
        self._actuator_id, self._fault_id = self.actuator.frame_id, self.fault.frame_id
        self.frame_ids = (self._actuator_id, self._fault_id)  # all the node handles
        self.actuator_check = self.actuator.checker(max_delta=2)
        self.fault_check = self.fault.checker(max_delta=14)  # event frames: any step forward
        rate_hz = 1.0 / plant.config.ecu_period_s
        self.every_analog = every_ticks(self.analog.cycle_time_ms, rate_hz)
        self.every_truth = every_ticks(self.truth_a.cycle_time_ms, rate_hz)
        self._actuator_raw = [0] * len(self.actuator.signal_names)
        self._fault_raw = [0] * len(self.fault.signal_names)
        self._sensors_raw = [0] * len(self.sensors.signal_names)
        self._analog_raw = [0] * len(self.analog.signal_names)
        self._truth_a_raw = [0] * len(self.truth_a.signal_names)
        self._truth_b_raw = [0] * len(self.truth_b.signal_names)
        self.actuator_late = 0  # actuator frames for a past tick (repeated or late)
        self.actuator_ahead = 0  # actuator frames for a tick not yet sent
        self.tick = 0  # ECU periods stepped (the tick whose command is awaited)
        self.duty = plant.trim_duty  # held until the first actuator frame
        self.pump_enabled = True
        self.fresh = False  # a valid actuator frame for this tick arrived (real time)
        self.missed = 0  # ticks in a row without a valid actuator frame
        self.watchdog_trips = 0
        self.actuator_rejected = 0  # E2E status other than OK
        self.faults_applied = 0
        self.faults_rejected = 0
        self._pending: list[tuple[int, int, float]] = []  # (absolute tick, target, value)
        self.timeout_s: float | None = None  # set while the ECU is silent (see on_timeout)
        self.finished = False
        # compiled packing (plants of plant/periphery.py): layout, counters and the payloads
        self._state = plant._s if isinstance(plant, PlantBase) else None
        self._messages = [codec[name] for name in FRAMES]
        self._ids = [m.frame_id for m in self._messages]
        self._layout = frame_layout(self._messages)
        self._frames = bytearray(8 * len(FRAMES))
        self._buf = np.frombuffer(self._frames, dtype=np.uint8)
        self._payload = [memoryview(self._frames)[8 * k : 8 * k + 8] for k in range(len(FRAMES))]
        if self._state is not None:  # compiled now too, on copies (the counters stay as they are)
            due = DUE_TRUTH | DUE_ANALOG
            pack_plant_frames(self._state, self._layout.copy(), self._buf.copy(), 0, 0, due)

    # -- frames in ---------------------------------------------------------------------------
    def start(self, send: SendFn) -> None:
        self._send_tick(send)

    def on_frame(self, frame_id: int, data: bytes | bytearray, send: SendFn) -> None:
        if frame_id == self._actuator_id:
            self._on_actuator(data, send)
        elif frame_id == self._fault_id:
            if self.fault_check.check(data) == E2EStatus.OK:
                raw = self._fault_raw
                self.fault.unpack_raw(data, raw)
                delta = (raw[1] - self.tick) % TICK_MODULO
                at = self.tick + (delta if delta < TICK_MODULO // 2 else 0)
                self._pending.append((at, raw[0], raw[2] * 1e-6))
            else:
                self.faults_rejected += 1

    def _on_actuator(self, data: bytes | bytearray, send: SendFn) -> None:
        if self.actuator_check.check(data) != E2EStatus.OK:
            self.actuator_rejected += 1
            return
        raw = self._actuator_raw
        self.actuator.unpack_raw(data, raw)
        if not self.lockstep:
            self._command(raw)
            return
        behind = (self.tick - raw[2]) % TICK_MODULO
        if behind != 0:  # not the answer to this tick: counted, and time does not move
            if behind < TICK_MODULO // 2:
                self.actuator_late += 1  # repeated or late
            else:
                self.actuator_ahead += 1  # a tick that has not been sent
            return
        self._command(raw)
        self._advance(send)

    def _command(self, raw: list) -> None:
        self.timeout_s = None
        self.pump_enabled = bool(raw[0])
        self.duty = _clamp(raw[3], 0, 10000) * 1e-4  # PumpDuty, 0.01 %
        self.fresh = True

    def on_timeout(self, send: SendFn) -> None:
        """Lockstep guard passed without the actuator frame: run the tick on the held command,
        and keep running on the node's own clock (one ECU period per period of silence) until
        actuator frames come back, so the pump driver's watchdog acts within its ticks."""
        self.timeout_s = self.plant.config.ecu_period_s
        self._advance(send)

    def on_period(self, send: SendFn) -> None:
        """Real time: one ECU period per period of the node's clock."""
        self._advance(send)

    # -- the compiled twin (see advance_compiled) ------------------------------------------------
    def compiled(self) -> bool:
        """The compiled lockstep functions can stand in for this node: lockstep, and a plant of
        plant/periphery.py whose period is one of KERNELS."""
        return self.lockstep and self._state is not None and type(self.plant).KERNEL in KERNELS

    def to_compiled(self, ns: np.ndarray, nf: np.ndarray) -> None:
        """The node's and its plant's state into the compiled functions' arrays (NS_SIZE int64,
        NF_SIZE float64). The plant's state array, the frames' layout and buffer are shared."""
        if not self.compiled():
            raise ValueError(f"{type(self.plant).__name__} node: no compiled twin")
        plant, check = self.plant, self.actuator_check
        assert isinstance(plant, PlantBase)
        ns[:] = 0
        ns[NS_TICK] = self.tick
        ns[NS_PLANT_TICK] = plant._tick
        ns[NS_NOISE_LEFT] = plant._noise_left
        ns[NS_FAULT_TICK] = min((f[0] for f in self._pending), default=NO_TICK)
        ns[NS_FLAGS] = plant.outputs.flags
        ns[NS_FRESH] = self.fresh
        ns[NS_MISSED] = self.missed
        ns[NS_WATCHDOG] = self.watchdog_ticks
        ns[NS_TRIPS] = self.watchdog_trips
        ns[NS_PUMP_ENABLED] = self.pump_enabled
        ns[NS_REJECTED] = self.actuator_rejected
        ns[NS_LATE] = self.actuator_late
        ns[NS_AHEAD] = self.actuator_ahead
        ns[NS_MAX_TICKS] = -1 if self.max_ticks is None else self.max_ticks
        ns[NS_FINISHED] = self.finished
        ns[NS_EVERY_TRUTH] = self.every_truth
        ns[NS_EVERY_ANALOG] = self.every_analog
        ns[NS_KERNEL] = KERNELS.index(type(plant).KERNEL)
        ns[NS_CHECK_LAST] = check._last_counter
        ns[NS_CHECK_STATUS] = check.status
        ns[NS_CHECK_CRC] = check._crc_start
        ns[NS_CHECK_COUNTS : NS_CHECK_COUNTS + len(E2EStatus)] = check.counts
        for i, (start, mask, sign_bit, _lo, _hi) in enumerate(self.actuator._fields):
            ns[NS_FIELDS + 3 * i : NS_FIELDS + 3 * i + 3] = (start, mask, sign_bit)
        nf[NF_DUTY] = self.duty
        nf[NF_FAULT_NEXT_S] = plant._faults.next_s
        nf[NF_PERIOD] = plant._period

    def from_compiled(self, ns: np.ndarray, nf: np.ndarray) -> None:
        """The state the compiled functions left in their arrays back into the node and plant
        (the plant's outputs as its last period published them)."""
        plant, check = self.plant, self.actuator_check
        assert isinstance(plant, PlantBase)
        self.tick = int(ns[NS_TICK])
        self.fresh = bool(ns[NS_FRESH])
        self.missed = int(ns[NS_MISSED])
        self.watchdog_trips = int(ns[NS_TRIPS])
        self.pump_enabled = bool(ns[NS_PUMP_ENABLED])
        self.actuator_rejected = int(ns[NS_REJECTED])
        self.actuator_late = int(ns[NS_LATE])
        self.actuator_ahead = int(ns[NS_AHEAD])
        self.finished = bool(ns[NS_FINISHED])
        self.duty = float(nf[NF_DUTY])
        check._last_counter = int(ns[NS_CHECK_LAST])
        check.status = E2EStatus(int(ns[NS_CHECK_STATUS]))
        check.counts = ns[NS_CHECK_COUNTS : NS_CHECK_COUNTS + len(E2EStatus)].tolist()
        if plant._tick != ns[NS_PLANT_TICK]:
            plant._tick = int(ns[NS_PLANT_TICK])
            plant._noise_left = int(ns[NS_NOISE_LEFT])
            plant.publish_outputs(int(ns[NS_FLAGS]))

    def python_part(self) -> None:
        """What of a lockstep advance runs in Python, before the period: the faults the node
        holds that fall due, then the plant's own (PlantBase.before_period)."""
        if self._pending:
            self._apply_faults()
        self.plant.before_period()

    # -- tick and frames out -----------------------------------------------------------------
    def _advance(self, send: SendFn) -> None:
        if self.fresh:
            self.missed = 0
        else:
            self.missed += 1
            if self.missed == self.watchdog_ticks + 1:
                self.watchdog_trips += 1
        self.fresh = False
        if self._pending:
            self._apply_faults()
        powered = self.pump_enabled and self.missed <= self.watchdog_ticks
        self.plant.step(self.duty if powered else 0.0, powered)
        self.tick += 1
        if self.max_ticks is not None and self.tick >= self.max_ticks:
            self.finished = True
        self._send_tick(send)

    def _apply_faults(self) -> None:
        due = [f for f in self._pending if f[0] <= self.tick]
        self._pending = [f for f in self._pending if f[0] > self.tick]
        for _, target, value in due:
            try:
                if target == CLEAR_ALL:
                    self.plant.clear_faults()
                else:
                    self._apply_fault(FAULT_TARGETS[target], value)
                self.faults_applied += 1
            except (KeyError, ValueError):
                self.faults_rejected += 1

    def _apply_fault(self, kind: FaultKind, value: float) -> None:
        if kind in SWITCHED or (kind in ENDED_BY_ZERO and value == 0.0):
            if kind in SWITCHED and value != 0.0:
                self.plant.inject(Fault(self.plant.time_s, kind))
            else:
                self.plant.end_fault(kind)
            return
        self.plant.inject(Fault(self.plant.time_s, kind, value))

    def _send_tick(self, send: SendFn) -> None:
        if self._state is None:
            self._send_tick_codec(send)
            return
        k = self.tick
        due = (DUE_TRUTH if k % self.every_truth == 0 else 0) | (
            DUE_ANALOG if k % self.every_analog == 0 else 0
        )
        pack_plant_frames(
            self._state, self._layout, self._buf, self.plant.outputs.flags, k % TICK_MODULO, due
        )
        ids, payload = self._ids, self._payload
        if due & DUE_TRUTH:
            send(ids[0], payload[0])
            send(ids[1], payload[1])
        if due & DUE_ANALOG:
            send(ids[2], payload[2])
        send(ids[3], payload[3])

    def _send_tick_codec(self, send: SendFn) -> None:
        o = self.plant.outputs
        k = self.tick
        tick16 = k % TICK_MODULO
        if k % self.every_truth == 0:
            raw = self._truth_a_raw
            raw[0] = 1 if o.flags & fl.FLAMEOUT else 0
            clamped = fl.COMPRESSOR_MAP_CLAMPED | fl.TURBINE_MAP_CLAMPED | fl.PUMP_MAP_CLAMPED
            raw[1] = 1 if o.flags & clamped else 0
            raw[2] = 1 if o.flags & fl.OVERSPEED else 0
            raw[3] = 1 if o.flags & fl.OVERTEMPERATURE else 0
            raw[4] = round(o.p3_pa * 0.1)
            raw[5] = round(o.p5_pa * 0.1)
            raw[6] = round(o.t4_k * 10.0)
            self.truth_a.pack_raw(raw)
            send(self.truth_a.frame_id, self.truth_a.data)
            raw = self._truth_b_raw
            raw[0] = round(o.fuel_kg_s * 1e6)
            raw[1] = round(o.thrust_n * 20.0)
            raw[2] = round(o.n_rpm)
            self.truth_b.pack_raw(raw)
            send(self.truth_b.frame_id, self.truth_b.data)
        if k % self.every_analog == 0:
            raw = self._analog_raw
            raw[0] = tick16
            raw[1] = round(o.supply_v * 1000.0)
            raw[2] = round(o.pump_current_a * 1000.0)
            self.analog.pack_raw(raw)
            send(self.analog.frame_id, self.analog.data)
        raw = self._sensors_raw
        raw[0] = tick16
        raw[1] = round(o.speed_rpm)
        raw[2] = round(o.egt_k * 10.0)
        self.sensors.pack_raw(raw)
        send(self.sensors.frame_id, self.sensors.data)
