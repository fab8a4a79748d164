"""The aero-thermal plant: engine (ch. 2) + gear pump and driver (sec. 2.2) + sensors + faults,
behind the one-ECU-period interface of plant/interface.py. One period is one compiled call,
``aero_period`` (see plant/periphery.py)."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit

from plant import engine as eng
from plant import flags as fl
from plant import hot_section as hs
from plant import ignition as ig
from plant.compressor import CompressorMap
from plant.engine import (
    EngineModel,
    EngineParams,
    Stations,
    advance_observed,
    stations,
)
from plant.faults import FaultKind
from plant.intake import intake
from plant.interface import SUBSTEP_S, Ambient, PlantConfig, PlantOutputs, check_finite
from plant.jit import EXACT
from plant.maps import EngineMaps, load_maps
from plant.periphery import (
    ENGINE,
    IGNITER,
    STARTER_DUTY,
    PlantBase,
    delivering,
    mat,
    pack_tables,
    publish,
    pump_driver,
    pump_health,
    pump_table_at,
    pump_tables,
    vec,
)
from plant.pump import pump_flow
from plant.starter import motor_current
from plant.trim import solve_steady, solve_steady_at_speed
from plant.turbine import TurbineMap

_PART_FAULT = {  # fault kind -> (engine parameter, its value while the fault lasts or None)
    FaultKind.STARTER_FAILURE: ("starter_health", None),
    FaultKind.IGNITER_FAILURE: ("igniter_health", 0.0),
    FaultKind.FUEL_STARVATION: ("fuel_supply_kg_s", None),
}
_HEALTH_FIELD = {  # fault kind -> (engine parameter, as-built value in PlantConfig)
    FaultKind.COMPRESSOR_EFFICIENCY: ("comp_eff_scale", "compressor_efficiency"),
    FaultKind.COMPRESSOR_FLOW: ("comp_flow_scale", "compressor_flow"),
    FaultKind.TURBINE_EFFICIENCY: ("turb_eff_scale", "turbine_efficiency"),
    FaultKind.TURBINE_FLOW: ("turb_flow_scale", "turbine_flow"),
}


# the engine's part of the state array: EngineParams, x, RK4 work, Stations, the engine's own
# states (plant.engine.advance_engine: ignition, metal, starter and igniter), substeps
PARAMS = ENGINE
X = PARAMS + len(EngineParams._fields)
WORK = X + 4
STATIONS = WORK + 20
Z = STATIONS + len(Stations._fields)
LIT = Z + eng.IGNITION + ig.LIT
METAL = Z + eng.METAL_K
N_SUB = Z + eng.ENGINE_SLOTS
_PARAM = {name: PARAMS + i for i, name in enumerate(EngineParams._fields)}
_INJECTOR_DP, _P0 = _PARAM["injector_dp_pa"], _PARAM["p0_pa"]
_PUMP_EFFECTIVENESS = _PARAM["pump_effectiveness"]
_EMF, _R_STARTER = _PARAM["starter_emf_v_s"], _PARAM["starter_r_ohm"]
_STARTER_HEALTH, _N_MAX = _PARAM["starter_health"], _PARAM["n_max_rpm"]


def model_tables(model: EngineModel) -> np.ndarray:
    """The model's tables for aero_period (plant.periphery.pack_tables)."""
    return pack_tables([*model.compressor, *model.turbine, *pump_tables(model.pump)])


@njit(**EXACT, inline="always")
def _model_at(s: np.ndarray, t: np.ndarray) -> EngineModel:
    p = PARAMS
    params = EngineParams(
        s[p], s[p + 1], s[p + 2], s[p + 3], s[p + 4], s[p + 5], s[p + 6], s[p + 7], s[p + 8],
        s[p + 9], s[p + 10], s[p + 11], s[p + 12], s[p + 13], s[p + 14], s[p + 15], s[p + 16],
        s[p + 17], s[p + 18], s[p + 19], s[p + 20], s[p + 21], s[p + 22], s[p + 23], s[p + 24],
        s[p + 25], s[p + 26], s[p + 27], s[p + 28],
    )  # fmt: skip
    compressor = CompressorMap(vec(t, 0), vec(t, 1), mat(t, 2), vec(t, 3), mat(t, 4), vec(t, 5))
    turbine = TurbineMap(vec(t, 6), vec(t, 7), mat(t, 8), mat(t, 9))
    return EngineModel(params, compressor, turbine, pump_table_at(t, 10, s))


@njit(**EXACT, inline="always")
def _starter_load(s: np.ndarray, supply_v: float) -> float:
    """Battery current of the starter at the supply voltage supply_v (duty x motor current)."""
    duty = s[STARTER_DUTY]
    if duty <= 0.0:
        return 0.0
    omega = s[X + 3] * 0.01 * s[_N_MAX] * math.pi / 30.0
    i = motor_current(duty * supply_v, omega, s[_EMF], s[_R_STARTER])
    return duty * s[_STARTER_HEALTH] * i


@njit(**EXACT)
def aero_period(
    s: np.ndarray, t: np.ndarray, u: float, pump_enabled: bool, tick: int, pump_in_loop: bool
) -> int:
    """One ECU period of the aero-thermal plant on its state array s and tables t: pump wear,
    driver, starter and battery at duty u (or, without the pump in the loop, fuel flow u), the
    engine (advance_observed), truth, limits and sensors into s. Returns the flags."""
    x = s[X : X + 4]
    if pump_in_loop and pump_health(s):
        s[_PUMP_EFFECTIVENESS] = delivering(s)
    duty = u if pump_in_loop else 0.0  # (without the pump in the loop: the battery alone)
    p_out = x[0] + s[_INJECTOR_DP] - s[_P0]
    supply, v_pump, current = pump_driver(s, duty, p_out)
    starter_a = 0.0
    if s[STARTER_DUTY] > 0.0:  # the starter's current sags the supply too
        starter_a = _starter_load(s, supply)
        supply, v_pump, current = pump_driver(s, duty, p_out, starter_a)
    if pump_in_loop:
        u = v_pump
    model = _model_at(s, t)
    z = s[Z:N_SUB]
    z[eng.STARTER_V] = s[STARTER_DUTY] * supply
    z[eng.IGNITER_ON] = s[IGNITER]
    out = s[STATIONS:Z]
    work = s[WORK : WORK + 20].reshape((5, 4))
    flags = advance_observed(x, u, pump_in_loop, z, int(s[N_SUB]), SUBSTEP_S, model, work, out)
    lit = z[eng.IGNITION + ig.LIT]
    if not pump_enabled:
        flags |= fl.PUMP_UNPOWERED
    flags |= int(out[10])
    if lit == 0.0:
        flags |= fl.FLAMEOUT
    # truth: N %, P3, P5, T4 of the state; EGT (t5), fuel, air flow (g2), thrust of the stations
    return publish(
        s, tick, flags, supply, v_pump, current, x[3], x[0], x[1], x[2], out[6], out[4], out[0],
        out[9], starter_a, z[eng.METAL_K] if z[eng.METAL_K] >= 0.0 else out[6],
        z[eng.IGNITION + ig.UNBURNT_KG], lit,
    )  # fmt: skip


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


class AeroThermalPlant(PlantBase):
    """Aero-thermal turbojet with gear pump, sensors and faults; ``step`` = one ECU period.

    Starts at the steady state of ``config.initial_fuel_kg_s`` (or of ``initial_speed_pct``
    within ``initial_egt_max_k``); ``trim_pump_voltage`` and ``trim_duty`` hold it there. With
    ``config.standstill`` it starts at rest, cold and unlit (both trims 0): the starter
    (``step(..., starter_duty=...)``) and the igniter start it.
    """

    ENGINE_SLOTS = N_SUB + 1 - ENGINE
    KERNEL = staticmethod(aero_period)

    def __init__(self, config: PlantConfig | None = None) -> None:
        config = PlantConfig() if config is None else config
        model = make_model(config.ambient)
        as_built = {param: getattr(config, field) for param, field in _HEALTH_FIELD.values()}
        self._model = model._replace(params=model.params._replace(**as_built))
        super().__init__(config, self._model.pump, self._model.params.n_max_rpm)
        self._tables = model_tables(self._model)
        s = self._s
        self._pump_changed()
        params = self._model.params._replace(pump_effectiveness=self.delivering_effectiveness)
        self._model = self._model._replace(params=params)  # as the trim below sees it
        s[PARAMS:X] = params
        self._refuse_unsupported(config.faults)
        s[N_SUB] = config.substeps
        if config.standstill:
            p2, t2 = intake(params.p0_pa, params.t0_k, params.u0_m_s)
            s[X : X + 4] = (p2, params.p0_pa, t2, 0.0)
            st = Stations(*stations(s[X : X + 4], 0.0, self._model))
            s[METAL] = t2 if config.hot_section_mass else hs.IN_EQUILIBRIUM
            self.trim_pump_voltage = self.trim_duty = 0.0
        else:
            g_fuel = config.initial_fuel_kg_s
            if config.initial_speed_pct is None:
                steady = solve_steady(self._model, g_fuel)
            else:
                g_fuel, steady = solve_steady_at_speed(
                    self._model, config.initial_speed_pct, config.initial_egt_max_k
                )
            s[X : X + 4] = steady.x
            s[LIT] = 1.0
            st = steady.stations
            s[METAL] = st.t5 if config.hot_section_mass else hs.IN_EQUILIBRIUM
            self.trim_pump_voltage = self._voltage_for(g_fuel)
            self.trim_duty = self._duty_for(self.trim_pump_voltage)
        s[STATIONS:Z] = st  # stations of the present state
        s[Z + eng.G3_KG_S] = max(st.g3, 0.0)
        self._start(st.t5, self.trim_duty)

    def step_fuel(self, fuel_kg_s: float) -> PlantOutputs:
        """Advance one ECU period with the fuel flow commanded directly (pump bypassed, no pump
        voltage or current), as the document's fuel staircases (figs. 2.14-2.17, 3.3)."""
        g_fuel = check_finite("fuel_kg_s", fuel_kg_s, 0.0, 0.05)
        return self._period_with(g_fuel, True, pump_in_loop=False)

    @property
    def state(self) -> np.ndarray:
        """Copy of x = [P3 Pa, P5 Pa, T4 K, N %]."""
        return self._s[X : X + 4].copy()

    @property
    def stations(self) -> Stations:
        """The station values at the present state (EGT in the t5 slot: the gas leaving the hot
        section)."""
        o = self._s[STATIONS:Z]
        return Stations(*o[:-1].tolist(), int(o[-1]))

    @property
    def model(self) -> EngineModel:
        """The compiled model's inputs as they are now (health and pump faults applied)."""
        return self._model._replace(params=EngineParams(*self._s[PARAMS:X].tolist()))

    # ---- engine side --------------------------------------------------------------------------
    def _truth(self, v_pump: float) -> tuple:
        s = self._s
        st = self.stations
        flags = st.flags | (fl.FLAMEOUT if s[LIT] == 0.0 else 0)
        x = s[X : X + 4]
        return (
            float(x[3]),
            float(x[0]),
            float(x[1]),
            float(x[2]),
            st.t5,
            st.g_fuel,
            st.g2,
            st.thrust,
            flags,
            float(s[METAL]) if s[METAL] >= 0.0 else st.t5,
            float(s[Z + eng.IGNITION + ig.UNBURNT_KG]),
            float(s[LIT]),
        )

    def _pump_outlet_gauge(self) -> float:
        s = self._s
        return float(s[X]) + float(s[_INJECTOR_DP]) - float(s[_P0])

    def _pump_changed(self) -> None:
        self._s[_PUMP_EFFECTIVENESS] = self.delivering_effectiveness

    def _supports(self, kind: FaultKind) -> bool:
        return True

    def _apply_engine(self, kind: FaultKind, value: float | None, starts: bool) -> None:
        if kind == FaultKind.AMBIENT_TEMPERATURE:
            t0 = value if starts else self.config.ambient.t0_k
            self._s[_PARAM["t0_k"]] = float(t0)
        elif kind in _PART_FAULT:
            param, during = _PART_FAULT[kind]
            new = getattr(EngineParams(0.0), param)  # a new part
            if starts:
                new = value if during is None else during
            self._s[_PARAM[param]] = float(new)
        else:
            value = value if starts else None
            param, as_built = _HEALTH_FIELD[kind]
            v = getattr(self.config, as_built) if value is None else float(value)
            self._s[_PARAM[param]] = v

    def _voltage_for(self, g_fuel: float) -> float:
        """Pump voltage that delivers g_fuel against the present P3 (bisection on the table)."""
        table, p_out = self._model.pump, self._pump_outlet_gauge()
        lo, hi = 0.0, float(table.voltage[-1])
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            q, _ = pump_flow(mid, p_out, table, self.delivering_effectiveness)
            lo, hi = (mid, hi) if q < g_fuel else (lo, mid)
        return 0.5 * (lo + hi)
