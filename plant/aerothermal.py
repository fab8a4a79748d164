"""The aero-thermal plant: engine (ch. 2) + gear pump and driver (sec. 2.2) + sensors + faults,
behind the one-ECU-period interface of plant/interface.py. One period is one compiled call,
``aero_period`` (see plant/periphery.py)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from plant import flags as fl
from plant.compressor import CompressorMap
from plant.engine import (
    EngineModel,
    EngineParams,
    Stations,
    advance_observed,
)
from plant.faults import FaultKind
from plant.interface import SUBSTEP_S, Ambient, PlantConfig, PlantOutputs, check_finite
from plant.jit import EXACT
from plant.maps import EngineMaps, load_maps
from plant.periphery import (
    BATTERY_V,
    ENGINE,
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
from plant.trim import solve_steady, solve_steady_at_speed
from plant.turbine import TurbineMap

_HEALTH_FIELD = {  # fault kind -> (engine parameter, as-built value in PlantConfig)
    FaultKind.COMPRESSOR_EFFICIENCY: ("comp_eff_scale", "compressor_efficiency"),
    FaultKind.COMPRESSOR_FLOW: ("comp_flow_scale", "compressor_flow"),
    FaultKind.TURBINE_EFFICIENCY: ("turb_eff_scale", "turbine_efficiency"),
    FaultKind.TURBINE_FLOW: ("turb_flow_scale", "turbine_flow"),
}


# the engine's part of the state array: EngineParams, x, RK4 work, Stations, lit, substeps
PARAMS = ENGINE
X = PARAMS + len(EngineParams._fields)
WORK = X + 4
STATIONS = WORK + 20
LIT = STATIONS + len(Stations._fields)
N_SUB = LIT + 1
_PARAM = {name: PARAMS + i for i, name in enumerate(EngineParams._fields)}
_INJECTOR_DP, _P0 = _PARAM["injector_dp_pa"], _PARAM["p0_pa"]
_PUMP_EFFECTIVENESS = _PARAM["pump_effectiveness"]


def model_tables(model: EngineModel) -> np.ndarray:
    """The model's tables for aero_period (plant.periphery.pack_tables)."""
    return pack_tables([*model.compressor, *model.turbine, *pump_tables(model.pump)])


@njit(**EXACT, inline="always")
def _model_at(s: np.ndarray, t: np.ndarray) -> EngineModel:
    p = PARAMS
    params = EngineParams(
        s[p], s[p + 1], s[p + 2], s[p + 3], s[p + 4], s[p + 5], s[p + 6], s[p + 7], s[p + 8],
        s[p + 9], s[p + 10], s[p + 11], s[p + 12], s[p + 13], s[p + 14], s[p + 15], s[p + 16],
        s[p + 17], s[p + 18], s[p + 19], s[p + 20], s[p + 21],
    )  # fmt: skip
    compressor = CompressorMap(vec(t, 0), vec(t, 1), mat(t, 2), vec(t, 3), mat(t, 4), vec(t, 5))
    turbine = TurbineMap(vec(t, 6), vec(t, 7), mat(t, 8), mat(t, 9))
    return EngineModel(params, compressor, turbine, pump_table_at(t, 10, s))


@njit(**EXACT)
def aero_period(
    s: np.ndarray, t: np.ndarray, u: float, pump_enabled: bool, tick: int, pump_in_loop: bool
) -> int:
    """One ECU period of the aero-thermal plant on its state array s and tables t: pump wear,
    driver and battery at duty u (or, without the pump in the loop, fuel flow u), the engine
    (advance_observed), truth, limits and sensors into s. Returns the flags."""
    if pump_in_loop:
        if pump_health(s):
            s[_PUMP_EFFECTIVENESS] = delivering(s)
        x = s[X : X + 4]
        supply, v_pump, current = pump_driver(s, u, x[0] + s[_INJECTOR_DP] - s[_P0])
        u = v_pump
    else:
        supply, v_pump, current = s[BATTERY_V], 0.0, 0.0
    model = _model_at(s, t)
    x = s[X : X + 4]
    out = s[STATIONS:LIT]
    work = s[WORK : WORK + 20].reshape((5, 4))
    flags, lit = advance_observed(
        x, u, pump_in_loop, s[LIT], int(s[N_SUB]), SUBSTEP_S, model, work, out
    )
    s[LIT] = lit
    if not pump_enabled:
        flags |= fl.PUMP_UNPOWERED
    flags |= int(out[10])
    if lit == 0.0:
        flags |= fl.FLAMEOUT
    # truth: N %, P3, P5, T4 of the state; EGT (t5), fuel, air flow (g2), thrust of the stations
    return publish(
        s, tick, flags, supply, v_pump, current, x[3], x[0], x[1], x[2], out[6], out[4], out[0],
        out[9],
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
    within ``initial_egt_max_k``); ``trim_pump_voltage`` and ``trim_duty`` hold it there.
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
        g_fuel = config.initial_fuel_kg_s
        if config.initial_speed_pct is None:
            steady = solve_steady(self._model, g_fuel)
        else:
            g_fuel, steady = solve_steady_at_speed(
                self._model, config.initial_speed_pct, config.initial_egt_max_k
            )
        s[X : X + 4] = steady.x
        s[LIT] = 1.0
        s[N_SUB] = config.substeps
        s[STATIONS:LIT] = steady.stations  # stations of the present state
        self.trim_pump_voltage = self._voltage_for(g_fuel)
        self.trim_duty = self._duty_for(self.trim_pump_voltage)
        self._start(steady.stations.t5, self.trim_duty)

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
    def model(self) -> EngineModel:
        """The compiled model's inputs as they are now (health and pump faults applied)."""
        return self._model._replace(params=EngineParams(*self._s[PARAMS:X].tolist()))

    # ---- engine side --------------------------------------------------------------------------
    def _truth(
        self, v_pump: float
    ) -> tuple[float, float, float, float, float, float, float, float, int]:
        s = self._s
        o = s[STATIONS:LIT]
        st = Stations(*o[:-1].tolist(), int(o[-1]))
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
        )

    def _pump_outlet_gauge(self) -> float:
        s = self._s
        return float(s[X]) + float(s[_INJECTOR_DP]) - float(s[_P0])

    def _pump_changed(self) -> None:
        self._s[_PUMP_EFFECTIVENESS] = self.delivering_effectiveness

    def _supports(self, kind: FaultKind) -> bool:
        return True

    def _apply_engine(self, kind: FaultKind, value: float | None) -> None:
        if kind == FaultKind.AMBIENT_TEMPERATURE:
            t0 = self.config.ambient.t0_k if value is None else value
            self._s[_PARAM["t0_k"]] = float(t0)
        else:
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
