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
EcuStarter frames set the starter's duty and the igniter from the next period on; after
``watchdog_ticks`` ticks without one the starter and igniter stop (the ECU sends them only while
it starts or stops the engine).
FaultInject frames schedule faults at their FaultTick (at once when that tick has passed);
a fault the plant cannot represent, or a value out of range, is counted and ignored.
The node reuses its buffers: nothing it keeps grows per frame or per tick. With a plant of
plant/periphery.py the frames of a tick are packed by one compiled call (plant/frames.py:
``pack_plant_frames``, the codec's layout, saturation, alive counters and E2E CRC, from the
plant's state array), which gives the bytes the codec's ``pack_raw`` gives; any other plant goes
through the codec. In lockstep the node has a compiled twin (plant/node_compiled.py).
"""

from __future__ import annotations

import copy

import numpy as np

from plant import flags as fl
from plant.faults import CLEAR_ALL, ENDED_BY_ZERO, FAULT_TARGETS, SWITCHED, Fault, FaultKind
from plant.frames import DUE_ANALOG, DUE_TRUTH, FRAMES, frame_layout, pack_plant_frames
from plant.interface import Plant
from plant.node_compiled import (
    KERNELS,
    NF_DUTY,
    NF_FAULT_NEXT_S,
    NF_PERIOD,
    NO_TICK,
    NS_AHEAD,
    NS_CHECK_COUNTS,
    NS_CHECK_CRC,
    NS_CHECK_LAST,
    NS_CHECK_STATUS,
    NS_EVERY_ANALOG,
    NS_EVERY_TRUTH,
    NS_FAULT_TICK,
    NS_FIELDS,
    NS_FINISHED,
    NS_FLAGS,
    NS_FRESH,
    NS_KERNEL,
    NS_LATE,
    NS_MAX_TICKS,
    NS_MISSED,
    NS_NOISE_LEFT,
    NS_PLANT_TICK,
    NS_PUMP_ENABLED,
    NS_REJECTED,
    NS_STARTER_MISSED,
    NS_TICK,
    NS_TRIPS,
    NS_WATCHDOG,
)
from plant.periphery import PlantBase
from protocol.codec import Codec
from protocol.e2e import E2EStatus
from protocol.lockstep import TICK_MODULO, every_ticks
from protocol.node import SendFn

DEFAULT_WATCHDOG_TICKS = 10


def _clamp(x: int, lo: int, hi: int) -> int:
    return lo if x < lo else hi if x > hi else x


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
        self.truth_c = codec["PlantTruthC"]
        self.actuator = codec["EcuActuator"]
        self.starter = codec["EcuStarter"]
        self.fault = codec["FaultInject"]
        self._actuator_id, self._fault_id = self.actuator.frame_id, self.fault.frame_id
        self._starter_id = self.starter.frame_id
        self.frame_ids = (self._actuator_id, self._starter_id, self._fault_id)  # all it handles
        self.actuator_check = self.actuator.checker(max_delta=2)
        self.starter_check = self.starter.checker(max_delta=2)
        self.fault_check = self.fault.checker(max_delta=14)  # event frames: any step forward
        rate_hz = 1.0 / plant.config.ecu_period_s
        self.every_analog = every_ticks(self.analog.cycle_time_ms, rate_hz)
        self.every_truth = every_ticks(self.truth_a.cycle_time_ms, rate_hz)
        self._actuator_raw = [0] * len(self.actuator.signal_names)
        self._fault_raw = [0] * len(self.fault.signal_names)
        self._starter_raw = [0] * len(self.starter.signal_names)
        self._sensors_raw = [0] * len(self.sensors.signal_names)
        self._analog_raw = [0] * len(self.analog.signal_names)
        self._truth_a_raw = [0] * len(self.truth_a.signal_names)
        self._truth_b_raw = [0] * len(self.truth_b.signal_names)
        self._truth_c_raw = [0] * len(self.truth_c.signal_names)
        self.actuator_late = 0  # actuator frames for a past tick (repeated or late)
        self.actuator_ahead = 0  # actuator frames for a tick not yet sent
        self.tick = 0  # ECU periods stepped (the tick whose command is awaited)
        self.duty = plant.trim_duty  # held until the first actuator frame
        self.pump_enabled = True
        self.starter_missed = 0  # ticks since the last valid EcuStarter frame
        self.starter_rejected = 0  # EcuStarter frames with an E2E status other than OK
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
        elif frame_id == self._starter_id:
            self._on_starter(data)
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

    def _on_starter(self, data: bytes | bytearray) -> None:
        if self.starter_check.check(data) != E2EStatus.OK:
            self.starter_rejected += 1
            return
        raw = self._starter_raw
        self.starter.unpack_raw(data, raw)
        self.starter_missed = 0
        self.plant.set_starter(_clamp(raw[2], 0, 10000) * 1e-4, bool(raw[0]))  # StarterDuty 0.01 %

    @property
    def starter_duty(self) -> float:
        """The starter's duty (0..1) as the plant runs it (0 after the watchdog)."""
        return self.plant.starter_command[0]

    @property
    def igniter(self) -> bool:
        """The igniter's power as the plant runs it."""
        return self.plant.starter_command[1]

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

    # -- the compiled twin (plant/node_compiled.py) ---------------------------------------------
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
        ns[NS_STARTER_MISSED] = self.starter_missed
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
        self.starter_missed = int(ns[NS_STARTER_MISSED])
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
        if self.starter_missed >= self.watchdog_ticks:  # no EcuStarter for the watchdog's time
            self.plant.set_starter(0.0, False)
        starter_duty, igniter = self.plant.starter_command
        self.plant.step(self.duty if powered else 0.0, powered, starter_duty, igniter)
        self.starter_missed += 1
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
            send(ids[2], payload[2])
        if due & DUE_ANALOG:
            send(ids[3], payload[3])
        send(ids[4], payload[4])

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
            raw = self._truth_c_raw
            raw[0] = 1 if o.burning else 0
            raw[1] = round(o.hot_section_k * 10.0)
            raw[2] = round(o.starter_current_a * 20.0)
            raw[3] = round(o.unburnt_fuel_kg * 1e6)
            self.truth_c.pack_raw(raw)
            send(self.truth_c.frame_id, self.truth_c.data)
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
