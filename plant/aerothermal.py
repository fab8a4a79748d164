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
    advance_observed,
)
from plant.faults import FaultKind
from plant.interface import SUBSTEP_S, Ambient, PlantConfig, PlantOutputs, check_finite
from plant.maps import EngineMaps, load_maps
from plant.periphery import PlantBase
from plant.pump import pump_flow
from plant.trim import solve_steady

_HEALTH_FIELD = {  # fault kind -> (engine parameter, as-built value in PlantConfig)
    FaultKind.COMPRESSOR_EFFICIENCY: ("comp_eff_scale", "compressor_efficiency"),
    FaultKind.COMPRESSOR_FLOW: ("comp_flow_scale", "compressor_flow"),
    FaultKind.TURBINE_EFFICIENCY: ("turb_eff_scale", "turbine_efficiency"),
    FaultKind.TURBINE_FLOW: ("turb_flow_scale", "turbine_flow"),
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


class AeroThermalPlant(PlantBase):
    """Aero-thermal turbojet with gear pump, sensors and faults; ``step`` = one ECU period.

    Starts at the steady state of ``config.initial_fuel_kg_s``; ``trim_pump_voltage`` and
    ``trim_duty`` hold it there.
    """

    def __init__(self, config: PlantConfig | None = None) -> None:
        config = PlantConfig() if config is None else config
        model = make_model(config.ambient)
        as_built = {param: getattr(config, field) for param, field in _HEALTH_FIELD.values()}
        self._model = model._replace(params=model.params._replace(**as_built))
        super().__init__(config, self._model.pump, self._model.params.n_max_rpm)
        self._pump_changed()
        self._refuse_unsupported(config.faults)
        steady = solve_steady(self._model, config.initial_fuel_kg_s)
        self._x = steady.x.copy()
        self._lit = 1.0
        self._work = np.empty((5, 4))
        self._n_sub = config.substeps
        self._out = np.array(steady.stations, dtype=float)  # stations of the present state
        self.trim_pump_voltage = self._voltage_for(config.initial_fuel_kg_s)
        self.trim_duty = self._duty_for(self.trim_pump_voltage)
        self._start(steady.stations.t5, self.trim_duty)

    def step_fuel(self, fuel_kg_s: float) -> PlantOutputs:
        """Advance one ECU period with the fuel flow commanded directly (pump bypassed, no pump
        voltage or current), as the document's fuel staircases (figs. 2.14-2.17, 3.3)."""
        g_fuel = check_finite("fuel_kg_s", fuel_kg_s, 0.0, 0.05)
        self._apply_due_faults()
        flags, self._lit = advance_observed(
            self._x,
            g_fuel,
            False,
            self._lit,
            self._n_sub,
            SUBSTEP_S,
            self._model,
            self._work,
            self._out,
        )
        self._tick += 1
        self._publish(flags, self._battery_v, 0.0, 0.0)
        return self.outputs

    @property
    def state(self) -> np.ndarray:
        """Copy of x = [P3 Pa, P5 Pa, T4 K, N %]."""
        return self._x.copy()

    @property
    def model(self) -> EngineModel:
        """The compiled model's inputs as they are now (health and pump faults applied)."""
        return self._model

    # ---- engine side --------------------------------------------------------------------------
    def _advance(self, v_pump: float) -> int:
        flags, self._lit = advance_observed(
            self._x,
            v_pump,
            True,
            self._lit,
            self._n_sub,
            SUBSTEP_S,
            self._model,
            self._work,
            self._out,
        )
        return flags

    def _truth(
        self, v_pump: float
    ) -> tuple[float, float, float, float, float, float, float, float, int]:
        o = self._out
        st = Stations(*o[:-1].tolist(), int(o[-1]))
        flags = st.flags | (fl.FLAMEOUT if self._lit == 0.0 else 0)
        x = self._x
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
        p = self._model.params
        return float(self._x[0]) + p.injector_dp_pa - p.p0_pa

    def _pump_changed(self) -> None:
        params = self._model.params._replace(pump_effectiveness=self.delivering_effectiveness)
        self._model = self._model._replace(params=params)

    def _supports(self, kind: FaultKind) -> bool:
        return True

    def _apply_engine(self, kind: FaultKind, value: float | None) -> None:
        if kind == FaultKind.AMBIENT_TEMPERATURE:
            t0 = self.config.ambient.t0_k if value is None else value
            params = self._model.params._replace(t0_k=float(t0))
        else:
            param, as_built = _HEALTH_FIELD[kind]
            params = self._model.params._replace(
                **{param: getattr(self.config, as_built) if value is None else float(value)}
            )
        self._model = self._model._replace(params=params)

    def _voltage_for(self, g_fuel: float) -> float:
        """Pump voltage that delivers g_fuel against the present P3 (bisection on the table)."""
        table, p_out = self._model.pump, self._pump_outlet_gauge()
        lo, hi = 0.0, float(table.voltage[-1])
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            q, _ = pump_flow(mid, p_out, table, self.delivering_effectiveness)
            lo, hi = (mid, hi) if q < g_fuel else (lo, mid)
        return 0.5 * (lo + hi)
