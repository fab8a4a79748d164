"""What both plants share around their engine: the pump driver and battery, the pump's health,
the sensors, the fault schedule and the one-ECU-period step (plant/interface.py)."""

from __future__ import annotations

from plant import flags as fl
from plant.faults import Fault, FaultKind, FaultSchedule
from plant.interface import PlantConfig, PlantOutputs, check_finite
from plant.noise import NoiseSource
from plant.pump import PumpState, PumpTable, supply_and_pump_voltage
from plant.sensors import SpeedPickup, Thermocouple

ENGINE_FAULTS = (  # handled by the engine side (_apply_engine)
    FaultKind.COMPRESSOR_EFFICIENCY,
    FaultKind.COMPRESSOR_FLOW,
    FaultKind.TURBINE_EFFICIENCY,
    FaultKind.TURBINE_FLOW,
    FaultKind.AMBIENT_TEMPERATURE,
)


class PlantBase:
    """One ECU period: faults due -> pump driver -> engine (subclass) -> sensors -> outputs.

    Subclasses implement ``_advance(v_pump) -> flags``, ``_truth()`` (the engine's present
    values), ``_pump_outlet_gauge() -> Pa``, ``_pump_changed()``, and for ENGINE_FAULTS
    ``_supports(kind)`` and ``_apply_engine(kind, value or None to end)``.
    """

    def __init__(self, config: PlantConfig, pump: PumpTable, n_max_rpm: float) -> None:
        self.config = config
        self._pump = pump
        self._n_max_rpm = n_max_rpm
        self._faults = FaultSchedule(config.faults)
        self._tick = 0
        self._battery_v = config.battery.voltage_v
        self._pump_state = PumpState.NORMAL
        self._effectiveness = config.pump_gain
        self._wear_rate = 0.0
        self.speed_pickup = SpeedPickup(config.speed_pickup, NoiseSource(config.seed))
        self.outputs = PlantOutputs()

    def _start(self, egt_k: float, duty: float) -> None:
        """Sensors settled at the initial state; outputs of tick 0 with the pump at ``duty``."""
        self.thermocouple = Thermocouple(
            self.config.thermocouple, NoiseSource(self.config.seed + 1), egt_k
        )
        supply, v_pump, current = supply_and_pump_voltage(
            duty,
            self._battery_v,
            self.config.battery.internal_resistance_ohm,
            self._pump_outlet_gauge(),
            self._pump,
            self._pump_state,
        )
        self._publish(0, supply, v_pump, current)

    # ---- inputs -------------------------------------------------------------------------------
    def step(self, pump_duty: float, pump_enabled: bool = True) -> PlantOutputs:
        """Advance one ECU period with the pump at ``pump_duty`` (0..1) of the supply voltage;
        ``pump_enabled=False`` removes pump power (duty ignored)."""
        duty = check_finite("pump_duty", pump_duty, 0.0, 1.0) if pump_enabled else 0.0
        self._apply_due_faults()
        if self._wear_rate > 0.0:
            self._effectiveness = max(
                self._effectiveness - self._wear_rate * self.config.ecu_period_s, 0.0
            )
            self._pump_changed()
        supply, v_pump, current = supply_and_pump_voltage(
            duty,
            self._battery_v,
            self.config.battery.internal_resistance_ohm,
            self._pump_outlet_gauge(),
            self._pump,
            self._pump_state,
        )
        flags = self._advance(v_pump)
        if not pump_enabled:
            flags |= fl.PUMP_UNPOWERED
        self._tick += 1
        self._publish(flags, supply, v_pump, current)
        return self.outputs

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

    def _publish(self, flags: int, supply: float, v_pump: float, current: float) -> None:
        c, o = self.config, self.outputs
        n_pct, p3, p5, t4, egt, fuel, air, thrust, engine_flags = self._truth(v_pump)
        flags |= engine_flags
        if n_pct > c.overspeed_pct:
            flags |= fl.OVERSPEED
        if egt > c.overtemperature_egt_k:
            flags |= fl.OVERTEMPERATURE
        n_rpm = n_pct * 0.01 * self._n_max_rpm
        o.tick = self._tick
        o.time_s = self.time_s
        o.speed_rpm = self.speed_pickup.read(n_rpm) if self._tick else n_rpm
        o.egt_k = self.thermocouple.read(egt, c.ecu_period_s) if self._tick else egt
        o.supply_v = supply
        o.pump_current_a = current
        o.n_rpm = n_rpm
        o.n_pct = n_pct
        o.p3_pa = p3
        o.p5_pa = p5
        o.t4_k = t4
        o.egt_true_k = egt
        o.fuel_kg_s = fuel
        o.air_kg_s = air
        o.thrust_n = thrust
        o.pump_v = v_pump
        o.pump_effectiveness = self._effectiveness
        o.flags = int(flags)

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
            self._apply_engine(k, value if starts else None)
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
    def _advance(self, v_pump: float) -> int:
        raise NotImplementedError

    def _truth(
        self, v_pump: float
    ) -> tuple[float, float, float, float, float, float, float, float, int]:
        """(N %, P3, P5, T4, EGT, fuel, air flow, thrust, flags) at the present state."""
        raise NotImplementedError

    def _pump_outlet_gauge(self) -> float:
        raise NotImplementedError

    def _pump_changed(self) -> None:
        raise NotImplementedError

    def _supports(self, kind: FaultKind) -> bool:
        raise NotImplementedError

    def _apply_engine(self, kind: FaultKind, value: float | None) -> None:
        raise NotImplementedError
