"""The aero-thermal plant: engine (ch. 2) + gear pump and driver (sec. 2.2) + sensors + faults,
behind the one-ECU-period interface of plant/interface.py."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from plant import flags as fl
from plant.engine import (
    EngineModel,
    EngineParams,
    Stations,
    advance_fuel,
    advance_pump,
    pump_fuel_flow,
    stations,
)
from plant.faults import Fault, FaultKind, FaultSchedule
from plant.interface import SUBSTEP_S, Ambient, PlantConfig, PlantOutputs, check_finite
from plant.maps import EngineMaps, load_maps
from plant.noise import NoiseSource
from plant.pump import PumpState, pump_flow, supply_and_pump_voltage
from plant.sensors import SpeedPickup, Thermocouple
from plant.trim import solve_steady

_HEALTH_FIELD = {
    FaultKind.COMPRESSOR_EFFICIENCY: "comp_eff_scale",
    FaultKind.COMPRESSOR_FLOW: "comp_flow_scale",
    FaultKind.TURBINE_EFFICIENCY: "turb_eff_scale",
    FaultKind.TURBINE_FLOW: "turb_flow_scale",
}


@lru_cache(maxsize=1)
def default_maps() -> EngineMaps:
    return load_maps()


def make_model(ambient: Ambient | None = None, maps: EngineMaps | None = None) -> EngineModel:
    """The calibrated engine at the given ambient conditions (default: sea-level static)."""
    ambient = Ambient() if ambient is None else ambient
    maps = default_maps() if maps is None else maps
    params = EngineParams(
        nozzle_area_m2=maps.nozzle_area_m2,
        p0_pa=float(ambient.p0_pa),
        t0_k=float(ambient.t0_k),
        u0_m_s=float(ambient.flight_speed_m_s),
    )
    return EngineModel(params, maps.compressor, maps.turbine, maps.pump)


class AeroThermalPlant:
    """Aero-thermal turbojet with gear pump, sensors and faults; ``step`` = one ECU period."""

    def __init__(self, config: PlantConfig | None = None) -> None:
        self.config = config = PlantConfig() if config is None else config
        self._model_new = make_model(config.ambient)
        self._health = self._model_new.params
        self._pump_state = PumpState.NORMAL
        self._wear_rate = 0.0
        self._battery_v = config.battery.voltage_v
        self._model = self._model_new
        steady = solve_steady(self._model, config.initial_fuel_kg_s)
        self._x = steady.x.copy()
        self._lit = 1.0
        self._work = np.empty((5, 4))
        self._faults = FaultSchedule(config.faults)
        self._n_sub = config.substeps
        self._tick = 0
        self.speed_pickup = SpeedPickup(config.speed_pickup, NoiseSource(config.seed))
        self.thermocouple = Thermocouple(
            config.thermocouple, NoiseSource(config.seed + 1), steady.stations.t5
        )
        self.trim_pump_voltage = self._voltage_for(config.initial_fuel_kg_s)
        self.trim_duty = self._duty_for(self.trim_pump_voltage)
        self.outputs = PlantOutputs()
        self._fill(steady.stations, 0, self._battery_v, 0.0, 0.0)

    # ---- inputs -------------------------------------------------------------------------------
    def step(self, pump_duty: float, pump_enabled: bool = True) -> PlantOutputs:
        """Advance one ECU period with the pump at ``pump_duty`` (0..1) of the supply voltage."""
        duty = check_finite("pump_duty", pump_duty, 0.0, 1.0) if pump_enabled else 0.0
        self._begin_period()
        p_out = self._pump_outlet_gauge()
        supply, v_pump, current = supply_and_pump_voltage(
            duty,
            self._battery_v,
            self.config.battery.internal_resistance_ohm,
            p_out,
            self._model.pump,
            self._pump_state,
        )
        flags, self._lit = advance_pump(
            self._x, v_pump, self._lit, self._n_sub, SUBSTEP_S, self._model, self._work
        )
        g_fuel, _ = pump_fuel_flow(self._x, v_pump, self._model)
        if not pump_enabled:
            flags |= fl.PUMP_UNPOWERED
        return self._end_period(g_fuel, flags, supply, v_pump, current)

    def step_fuel(self, fuel_kg_s: float) -> PlantOutputs:
        """Advance one ECU period with the fuel flow commanded directly (pump bypassed), as the
        document's fuel staircases (figs. 2.14-2.17, 3.3)."""
        g_fuel = check_finite("fuel_kg_s", fuel_kg_s, 0.0, 0.05)
        self._begin_period()
        flags, self._lit = advance_fuel(
            self._x, g_fuel, self._lit, self._n_sub, SUBSTEP_S, self._model, self._work
        )
        return self._end_period(g_fuel, flags, self._battery_v, 0.0, 0.0)

    def inject(self, fault: Fault) -> None:
        """Schedule a fault; one whose time has passed applies at the next step."""
        self._faults.add(fault)

    # ---- state --------------------------------------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """Copy of x = [P3 Pa, P5 Pa, T4 K, N %]."""
        return self._x.copy()

    @property
    def time_s(self) -> float:
        return self._tick * self.config.ecu_period_s

    @property
    def model(self) -> EngineModel:
        return self._model

    # ---- internals ----------------------------------------------------------------------------
    def _begin_period(self) -> None:
        for fault, starts in self._faults.due(self.time_s):
            self._apply(fault, starts)
        if self._wear_rate > 0.0:
            eff = max(
                self._health.pump_effectiveness - self._wear_rate * self.config.ecu_period_s, 0.0
            )
            self._set_health(pump_effectiveness=eff)

    def _end_period(
        self, g_fuel: float, flags: int, supply: float, v_pump: float, current: float
    ) -> PlantOutputs:
        self._tick += 1
        st = Stations(*stations(self._x, g_fuel, self._model))
        self._fill(st, flags | st.flags, supply, v_pump, current)
        return self.outputs

    def _fill(self, st: Stations, flags: int, supply: float, v_pump: float, current: float) -> None:
        c, o, x = self.config, self.outputs, self._x
        n_rpm = x[3] * 0.01 * self._model.params.n_max_rpm
        if self._lit == 0.0:
            flags |= fl.FLAMEOUT
        if x[3] > c.overspeed_pct:
            flags |= fl.OVERSPEED
        if st.t5 > c.overtemperature_egt_k:
            flags |= fl.OVERTEMPERATURE
        o.tick = self._tick
        o.time_s = self.time_s
        o.speed_rpm = self.speed_pickup.read(n_rpm) if self._tick else n_rpm
        o.egt_k = self.thermocouple.read(st.t5, c.ecu_period_s) if self._tick else st.t5
        o.supply_v = supply
        o.pump_current_a = current
        o.n_rpm = n_rpm
        o.n_pct = float(x[3])
        o.p3_pa = float(x[0])
        o.p5_pa = float(x[1])
        o.t4_k = float(x[2])
        o.egt_true_k = st.t5
        o.fuel_kg_s = st.g_fuel
        o.air_kg_s = st.g2
        o.thrust_n = st.thrust
        o.pump_v = v_pump
        o.pump_effectiveness = self._health.pump_effectiveness
        o.flags = int(flags)

    def _pump_outlet_gauge(self) -> float:
        p = self._model.params
        return float(self._x[0]) + p.injector_dp_pa - p.p0_pa

    def _apply(self, fault: Fault, starts: bool) -> None:
        k = fault.kind
        if k in _HEALTH_FIELD:
            self._set_health(**{_HEALTH_FIELD[k]: fault.value if starts else 1.0})
        elif k == FaultKind.PUMP_EFFECTIVENESS:
            self._set_health(pump_effectiveness=fault.value if starts else 1.0)
        elif k == FaultKind.PUMP_WEAR:
            self._wear_rate = fault.value if starts else 0.0
        elif k in (FaultKind.PUMP_DRY, FaultKind.PUMP_STALL):
            state = PumpState.DRY if k == FaultKind.PUMP_DRY else PumpState.STALLED
            self._pump_state = state if starts else PumpState.NORMAL
            self._set_health()
        elif k == FaultKind.SPEED_DROPOUT:
            self.speed_pickup.dropout = starts
        elif k == FaultKind.SPEED_STUCK:
            self.speed_pickup.stuck = starts
        elif k == FaultKind.SPEED_NOISE_BURST:
            self.speed_pickup.burst_noise_rpm = fault.value if starts else 0.0
        elif k == FaultKind.EGT_OPEN_CIRCUIT:
            self.thermocouple.open_circuit = starts
        elif k == FaultKind.BATTERY_VOLTAGE:
            self._battery_v = fault.value if starts else self.config.battery.voltage_v

    def _set_health(self, **changes: float) -> None:
        """Update health parameters; the compiled model sees a dry or stalled pump as delivering
        nothing."""
        self._health = self._health._replace(**{k: float(v) for k, v in changes.items()})
        delivering = self._pump_state == PumpState.NORMAL
        params = self._health._replace(
            pump_effectiveness=self._health.pump_effectiveness if delivering else 0.0
        )
        self._model = self._model._replace(params=params)

    def _voltage_for(self, g_fuel: float) -> float:
        """Pump voltage that delivers g_fuel against the present P3 (bisection on the table)."""
        table, p_out = self._model.pump, self._pump_outlet_gauge()
        lo, hi = 0.0, float(table.voltage[-1])
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if pump_flow(mid, p_out, table, self._health.pump_effectiveness)[0] < g_fuel:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def _duty_for(self, v_pump: float) -> float:
        """Duty giving v_pump at the pump terminals with the battery sagging under load."""
        lo, hi = 0.0, 1.0
        b = self.config.battery
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            _, v, _ = supply_and_pump_voltage(
                mid,
                self._battery_v,
                b.internal_resistance_ohm,
                self._pump_outlet_gauge(),
                self._model.pump,
                self._pump_state,
            )
            if v < v_pump:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)
