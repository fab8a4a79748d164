"""What both plants share around their engine: the pump driver and battery, the pump's health,
the sensors, the fault schedule and the one-ECU-period step (plant/interface.py).

One ECU period is one compiled call (the subclass's kernel) on one preallocated float64 array,
the plant's state: the driver's, pump's and sensors' scalars (slots below), the outputs of the
last period, the sensors' noise blocks, then the engine's own part from ENGINE. The kernels
build on the compiled pieces here (``pump_health``, ``pump_driver``, ``publish``), which do the
float arithmetic of the Python they replaced operation for operation (plant.jit.EXACT), and call
the engine as its own compiled function. Python keeps what happens seldom: checking the duty,
faults as they fall due, refilling the noise blocks every BLOCK periods, and the outputs record.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from plant import flags as fl
from plant.faults import ENGINE_FAULTS, Fault, FaultKind, FaultSchedule
from plant.interface import PlantConfig, PlantOutputs, check_finite
from plant.jit import EXACT
from plant.noise import BLOCK, NoiseSource
from plant.pump import PumpState, PumpTable, supply_and_pump_voltage
from plant.sensors import (
    SP_SLOTS,
    TC_SLOTS,
    SpeedPickup,
    Thermocouple,
    speed_reading,
    thermocouple_reading,
)

# ---- the state array --------------------------------------------------------------------------
(
    PERIOD,  # ECU period, s
    BATTERY_V,  # open-circuit battery voltage (the fault's, or the configured)
    BATTERY_R,  # internal resistance, ohm
    EFFECTIVENESS,  # pump effectiveness (wear and the fault act on it)
    WEAR_RATE,  # effectiveness lost per second
    PUMP_STATE,  # PumpState
    IDLE_A,  # pump current model (PumpTable)
    PER_VOLT,
    PER_PA,
    N_MAX_RPM,
    OVERSPEED_PCT,
    OVERTEMPERATURE_K,
    NOISE_INDEX,  # next sample of the noise blocks
    STARTER_DUTY,  # the starter's PWM duty, 0..1 (input)
    IGNITER,  # 1 while the igniter is powered (input)
) = range(15)
SPEED = 16  # the speed pickup's slots (plant.sensors)
THERMO = SPEED + SP_SLOTS  # the thermocouple's
OUT = 32  # the outputs of the last period, in OUT_FIELDS order
OUT_FIELDS = (
    "time_s",
    "speed_rpm",
    "egt_k",
    "supply_v",
    "pump_current_a",
    "n_rpm",
    "n_pct",
    "p3_pa",
    "p5_pa",
    "t4_k",
    "egt_true_k",
    "fuel_kg_s",
    "air_kg_s",
    "thrust_n",
    "pump_v",
    "pump_effectiveness",
    "starter_current_a",
    "hot_section_k",
    "unburnt_fuel_kg",
    "burning",
)
NOISE = OUT + len(OUT_FIELDS)  # three blocks: speed normal, speed uniform, thermocouple normal
ENGINE = NOISE + 3 * BLOCK  # the subclass's part
assert THERMO + TC_SLOTS <= OUT
_NORMAL, _DRY, _STALLED = int(PumpState.NORMAL), int(PumpState.DRY), int(PumpState.STALLED)


@njit(**EXACT, inline="always")
def pump_health(s: np.ndarray) -> bool:
    """Gradual wear over one period; True when the effectiveness changed."""
    rate = s[WEAR_RATE]
    if rate > 0.0:
        e = s[EFFECTIVENESS] - rate * s[PERIOD]
        s[EFFECTIVENESS] = 0.0 if 0.0 > e else e  # max(e, 0.0)
        return True
    return False


@njit(**EXACT, inline="always")
def delivering(s: np.ndarray) -> float:
    """Pump effectiveness as the engine sees it (0 while the pump is dry or stalled)."""
    return s[EFFECTIVENESS] if s[PUMP_STATE] == _NORMAL else 0.0


@njit(**EXACT, inline="always")
def pump_driver(
    s: np.ndarray, duty: float, p_out_gauge_pa: float, other_load_a: float = 0.0
) -> tuple[float, float, float]:
    """(supply voltage, pump voltage, pump current): plant.pump.supply_and_pump_voltage and
    pump_current, compiled; other_load_a, drawn from the battery beside the pump (the
    starter), sags the supply too."""
    r = s[BATTERY_R]
    battery_v = s[BATTERY_V] - r * other_load_a
    state = s[PUMP_STATE]
    if state == _STALLED or duty <= 0.0:
        return battery_v, 0.0, 0.0
    p_pos = 0.0 if 0.0 > p_out_gauge_pa else p_out_gauge_pa  # max(p, 0.0)
    load = s[IDLE_A]
    if state != _DRY:
        load += s[PER_PA] * p_pos
    v_pump = duty * (battery_v - r * load) / (1.0 + duty * r * s[PER_VOLT])
    if 0.0 > v_pump:
        v_pump = 0.0
    if v_pump <= 0.0:
        current = 0.0
    else:
        current = s[IDLE_A] + s[PER_VOLT] * v_pump
        if state != _DRY:
            current = current + s[PER_PA] * p_pos
    return battery_v - r * current, v_pump, current


@njit(**EXACT, inline="always")
def publish(
    s: np.ndarray,
    tick: int,
    flags: int,
    supply: float,
    v_pump: float,
    current: float,
    n_pct: float,
    p3: float,
    p5: float,
    t4: float,
    egt: float,
    fuel: float,
    air: float,
    thrust: float,
    starter_a: float,
    metal_k: float,
    unburnt_kg: float,
    burning: float,
) -> int:
    """Limits, sensor readings (one sample of each noise block) and the outputs of the period
    into s[OUT:]; returns the flags."""
    if n_pct > s[OVERSPEED_PCT]:
        flags |= fl.OVERSPEED
    if egt > s[OVERTEMPERATURE_K]:
        flags |= fl.OVERTEMPERATURE
    n_rpm = n_pct * 0.01 * s[N_MAX_RPM]
    i = int(s[NOISE_INDEX])
    s[NOISE_INDEX] = i + 1
    speed = speed_reading(s, SPEED, n_rpm, s[NOISE + i], s[NOISE + BLOCK + i])
    egt_k = thermocouple_reading(s, THERMO, egt, s[NOISE + 2 * BLOCK + i])
    s[OUT] = tick * s[PERIOD]
    s[OUT + 1] = speed
    s[OUT + 2] = egt_k
    s[OUT + 3] = supply
    s[OUT + 4] = current
    s[OUT + 5] = n_rpm
    s[OUT + 6] = n_pct
    s[OUT + 7] = p3
    s[OUT + 8] = p5
    s[OUT + 9] = t4
    s[OUT + 10] = egt
    s[OUT + 11] = fuel
    s[OUT + 12] = air
    s[OUT + 13] = thrust
    s[OUT + 14] = v_pump
    s[OUT + 15] = s[EFFECTIVENESS]
    s[OUT + 16] = starter_a
    s[OUT + 17] = metal_k
    s[OUT + 18] = unburnt_kg
    s[OUT + 19] = burning
    return flags


def pack_tables(arrays: list[np.ndarray]) -> np.ndarray:
    """Float64 arrays (1-D or 2-D) in one flat array the kernels unpack with ``vec``/``mat``:
    a header of (offset, rows, columns) per array, then the arrays' data."""
    head = 3 * len(arrays)
    sizes = [a.size for a in arrays]
    flat = np.empty(head + sum(sizes))
    at = head
    for k, a in enumerate(arrays):
        flat[3 * k : 3 * k + 3] = (at, a.shape[0], a.shape[1] if a.ndim == 2 else 0)
        flat[at : at + a.size] = a.ravel()
        at += a.size
    return flat


@njit(**EXACT, inline="always")
def vec(t: np.ndarray, k: int) -> np.ndarray:
    at, n = int(t[3 * k]), int(t[3 * k + 1])
    return t[at : at + n]


@njit(**EXACT, inline="always")
def mat(t: np.ndarray, k: int) -> np.ndarray:
    at, rows, cols = int(t[3 * k]), int(t[3 * k + 1]), int(t[3 * k + 2])
    return t[at : at + rows * cols].reshape((rows, cols))


def pump_tables(pump: PumpTable) -> list[np.ndarray]:
    return [pump.voltage, pump.pressure, pump.flow]


@njit(**EXACT, inline="always")
def pump_table_at(t: np.ndarray, k: int, s: np.ndarray) -> PumpTable:
    """The PumpTable from tables k..k+2 of ``t`` and the current model in ``s``."""
    return PumpTable(vec(t, k), vec(t, k + 1), mat(t, k + 2), s[IDLE_A], s[PER_VOLT], s[PER_PA])


class PlantBase:
    """One ECU period: faults due -> pump driver -> engine (subclass) -> sensors -> outputs.

    Subclasses set ``ENGINE_SLOTS`` (their part of the state array), ``KERNEL`` (the compiled
    period: ``KERNEL(state, tables, u, pump_enabled, tick, pump_in_loop) -> flags``, u the duty
    when pump_in_loop, else the fuel flow) and ``_tables``, and implement ``_truth()`` (the
    engine's present values, for the outputs of tick 0), ``_pump_outlet_gauge() -> Pa``,
    ``_pump_changed()``, and for ENGINE_FAULTS ``_supports(kind)`` and
    ``_apply_engine(kind, value, starts)`` (starts False: the fault ends).
    """

    ENGINE_SLOTS = 0
    KERNEL = None

    def __init__(self, config: PlantConfig, pump: PumpTable, n_max_rpm: float) -> None:
        self.config = config
        self._pump = pump
        self._n_max_rpm = n_max_rpm
        self._period = config.ecu_period_s
        self._faults = FaultSchedule(config.faults)
        self._tick = 0
        s = self._s = np.zeros(ENGINE + self.ENGINE_SLOTS)
        s[PERIOD] = config.ecu_period_s
        s[BATTERY_V] = config.battery.voltage_v
        s[BATTERY_R] = config.battery.internal_resistance_ohm
        s[EFFECTIVENESS] = config.pump_gain
        s[PUMP_STATE] = PumpState.NORMAL
        s[IDLE_A], s[PER_VOLT], s[PER_PA] = (
            pump.current_idle_a,
            pump.current_per_volt,
            pump.current_per_pa,
        )
        s[N_MAX_RPM] = n_max_rpm
        s[OVERSPEED_PCT] = config.overspeed_pct
        s[OVERTEMPERATURE_K] = config.overtemperature_egt_k
        self.speed_pickup = SpeedPickup(config.speed_pickup, s, SPEED)
        self._noise = (NoiseSource(config.seed), NoiseSource(config.seed + 1))
        self._noise_left = 0  # samples left in the blocks (one of each is read per period)
        self.outputs = PlantOutputs()

    # ---- state in the array -------------------------------------------------------------------
    @property
    def _battery_v(self) -> float:
        return float(self._s[BATTERY_V])

    @_battery_v.setter
    def _battery_v(self, v: float) -> None:
        self._s[BATTERY_V] = v

    @property
    def _effectiveness(self) -> float:
        return float(self._s[EFFECTIVENESS])

    @_effectiveness.setter
    def _effectiveness(self, e: float) -> None:
        self._s[EFFECTIVENESS] = e

    @property
    def _wear_rate(self) -> float:
        return float(self._s[WEAR_RATE])

    @_wear_rate.setter
    def _wear_rate(self, rate: float) -> None:
        self._s[WEAR_RATE] = rate

    @property
    def _pump_state(self) -> PumpState:
        return PumpState(int(self._s[PUMP_STATE]))

    @_pump_state.setter
    def _pump_state(self, state: PumpState) -> None:
        self._s[PUMP_STATE] = state

    def _start(self, egt_k: float, duty: float) -> None:
        """Sensors settled at the initial state; outputs of tick 0 with the pump at ``duty``."""
        self.thermocouple = Thermocouple(
            self.config.thermocouple, self._s, THERMO, egt_k, self.config.ecu_period_s
        )
        supply, v_pump, current = supply_and_pump_voltage(
            duty,
            self._battery_v,
            self.config.battery.internal_resistance_ohm,
            self._pump_outlet_gauge(),
            self._pump,
            self._pump_state,
        )
        c, o = self.config, self.outputs
        n_pct, p3, p5, t4, egt, fuel, air, thrust, flags, metal, unburnt, burning = self._truth(
            v_pump
        )
        if n_pct > c.overspeed_pct:
            flags |= fl.OVERSPEED
        if egt > c.overtemperature_egt_k:
            flags |= fl.OVERTEMPERATURE
        n_rpm = n_pct * 0.01 * self._n_max_rpm
        values = (0.0, n_rpm, egt, supply, current, n_rpm, n_pct, p3, p5, t4, egt, fuel, air)
        values += (thrust, v_pump, self._effectiveness, 0.0, metal, unburnt, burning)
        for name, value in zip(OUT_FIELDS, values, strict=True):
            setattr(o, name, value)
        self._s[OUT : OUT + len(OUT_FIELDS)] = values
        o.tick = 0
        o.flags = int(flags)

    # ---- inputs -------------------------------------------------------------------------------
    def step(
        self,
        pump_duty: float,
        pump_enabled: bool = True,
        starter_duty: float = 0.0,
        igniter: bool = False,
    ) -> PlantOutputs:
        """Advance one ECU period with the pump at ``pump_duty`` (0..1) of the supply voltage;
        ``pump_enabled=False`` removes pump power (duty ignored); the starter at
        ``starter_duty`` (0..1) of the supply and the igniter powered or not over the period (a
        plant without them ignores them)."""
        self.set_starter(starter_duty, igniter)
        if not pump_enabled:
            duty = 0.0
        elif type(pump_duty) is float and 0.0 <= pump_duty <= 1.0:
            duty = pump_duty
        else:
            duty = check_finite("pump_duty", pump_duty, 0.0, 1.0)
        return self._period_with(duty, bool(pump_enabled))

    @property
    def starter_command(self) -> tuple[float, bool]:
        """The starter's duty and the igniter's power as the plant runs them now."""
        return float(self._s[STARTER_DUTY]), bool(self._s[IGNITER])

    def set_starter(self, starter_duty: float, igniter: bool) -> None:
        """The starter's duty (0..1 of the supply) and the igniter's power, from now on."""
        s = self._s
        if type(starter_duty) is not float or not 0.0 <= starter_duty <= 1.0:
            starter_duty = check_finite("starter_duty", starter_duty, 0.0, 1.0)
        s[STARTER_DUTY] = starter_duty
        s[IGNITER] = 1.0 if igniter else 0.0

    def _period_with(self, u: float, pump_enabled: bool, pump_in_loop: bool = True) -> PlantOutputs:
        """One period: faults due, the kernel with input u, the outputs."""
        self.before_period()
        tick = self._tick + 1
        flags = self.KERNEL(self._s, self._tables, u, pump_enabled, tick, pump_in_loop)
        self._noise_left -= 1
        self._tick = tick
        return self.publish_outputs(flags)

    def before_period(self) -> None:
        """The part of a period that stays in Python, before the kernel: the faults that fall
        due, and new noise blocks when the last ones are used up."""
        if self._faults.next_s <= self._tick * self._period + 1e-9:
            self._apply_due_faults()
        if not self._noise_left:
            self._refill_noise()

    def publish_outputs(self, flags: int) -> PlantOutputs:
        """The outputs record from the state array after a period (its tick, the flags)."""
        o = self.outputs
        (
            o.time_s,
            o.speed_rpm,
            o.egt_k,
            o.supply_v,
            o.pump_current_a,
            o.n_rpm,
            o.n_pct,
            o.p3_pa,
            o.p5_pa,
            o.t4_k,
            o.egt_true_k,
            o.fuel_kg_s,
            o.air_kg_s,
            o.thrust_n,
            o.pump_v,
            o.pump_effectiveness,
            o.starter_current_a,
            o.hot_section_k,
            o.unburnt_fuel_kg,
            o.burning,
        ) = self._s[OUT:NOISE].tolist()
        o.tick = self._tick
        o.flags = flags
        return o

    def _refill_noise(self) -> None:
        speed, thermo = self._noise
        s = self._s
        s[NOISE : NOISE + BLOCK] = speed.normal_block()
        s[NOISE + BLOCK : NOISE + 2 * BLOCK] = speed.uniform_block()
        s[NOISE + 2 * BLOCK : ENGINE] = thermo.normal_block()
        s[NOISE_INDEX] = 0.0
        self._noise_left = BLOCK

    def inject(self, fault: Fault) -> None:
        """Schedule a fault; one whose time has passed applies at the next step. A fault this
        plant cannot represent raises ValueError."""
        self._refuse_unsupported((fault,))
        self._faults.add(fault)

    @property
    def time_s(self) -> float:
        """Simulated time: ECU periods stepped so far times the period."""
        return self._tick * self.config.ecu_period_s

    @property
    def delivering_effectiveness(self) -> float:
        """Pump effectiveness as the engine sees it (0 while the pump is dry or stalled)."""
        return self._effectiveness if self._pump_state == PumpState.NORMAL else 0.0

    # ---- internals ----------------------------------------------------------------------------
    def _refuse_unsupported(self, faults: tuple[Fault, ...]) -> None:
        for fault in faults:
            if not self._supports(fault.kind):
                raise ValueError(
                    f"fault {fault.kind.value}: {type(self).__name__} has no such part"
                )

    def _apply_due_faults(self) -> None:
        for fault, starts in self._faults.due(self.time_s):
            self._apply(fault.kind, fault.value, starts)

    def end_fault(self, kind: FaultKind) -> None:
        """End a fault of this kind now (its effect returns to the configured value)."""
        self._apply(FaultKind(kind), None, False)

    def clear_faults(self) -> None:
        """End every fault now and forget the scheduled ones."""
        self._faults = FaultSchedule()
        for kind in FaultKind:
            if self._supports(kind):
                self._apply(kind, None, False)

    def _apply(self, k: FaultKind, value: float | None, starts: bool) -> None:
        """Start (with its value) or end a fault of kind k."""
        if k in ENGINE_FAULTS:
            self._apply_engine(k, value, starts)
        elif k == FaultKind.PUMP_EFFECTIVENESS:
            gain = self.config.pump_gain  # the fault's value is relative to the new pump
            self._effectiveness = value * gain if starts else gain
            self._pump_changed()
        elif k == FaultKind.PUMP_WEAR:
            self._wear_rate = value if starts else 0.0
        elif k in (FaultKind.PUMP_DRY, FaultKind.PUMP_STALL):
            state = PumpState.DRY if k == FaultKind.PUMP_DRY else PumpState.STALLED
            self._pump_state = state if starts else PumpState.NORMAL
            self._pump_changed()
        elif k == FaultKind.SPEED_DROPOUT:
            self.speed_pickup.dropout = starts
        elif k == FaultKind.SPEED_STUCK:
            self.speed_pickup.stuck = starts
        elif k == FaultKind.SPEED_NOISE_BURST:
            self.speed_pickup.burst_noise_rpm = value if starts else 0.0
        elif k == FaultKind.EGT_OPEN_CIRCUIT:
            self.thermocouple.open_circuit = starts
        elif k == FaultKind.BATTERY_VOLTAGE:
            self._battery_v = value if starts else self.config.battery.voltage_v

    def _duty_for(self, v_pump: float) -> float:
        """Duty giving v_pump at the pump terminals now, with the battery sagging under load."""
        lo, hi = 0.0, 1.0
        r = self.config.battery.internal_resistance_ohm
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            _, v, _ = supply_and_pump_voltage(
                mid, self._battery_v, r, self._pump_outlet_gauge(), self._pump, self._pump_state
            )
            lo, hi = (mid, hi) if v < v_pump else (lo, mid)
        return 0.5 * (lo + hi)

    # ---- engine side (subclasses) -------------------------------------------------------------
    def _truth(self, v_pump: float) -> tuple:
        """(N %, P3, P5, T4, EGT, fuel, air flow, thrust, flags, hot-section metal K, unburnt
        fuel kg, burning 0/1) at the present state."""
        raise NotImplementedError

    def _pump_outlet_gauge(self) -> float:
        raise NotImplementedError

    def _pump_changed(self) -> None:
        raise NotImplementedError

    def _supports(self, kind: FaultKind) -> bool:
        raise NotImplementedError

    def _apply_engine(self, kind: FaultKind, value: float | None, starts: bool) -> None:
        raise NotImplementedError
