"""The fast engine model of eq. 3.24 as a second plant with the interface of plant/interface.py.

Shaft dynamics from eq. 3.24 (deviations from the trim N = 89.68 %, V = the aero-thermal trim
pump voltage); pump driver, battery and sensors as in the aero-thermal plant. What the fast model
does not have (P3, P5, T4, EGT, thrust, air flow) is read off the aero-thermal running line at
the present speed, quasi-steadily. Pump effectiveness scales the input terms theta2..theta4, as
the document's failure does (sec. 4.2, ch. 6); a dry or stalled pump is effectiveness 0, which in
this model means "no response to the voltage", not a flameout. Compressor and turbine health
and ambient faults have no counterpart here and are refused.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from plant.aerothermal import default_maps, make_model
from plant.fast_model import THETA_EQ_3_23, TRIM_N_PCT, fast_model_derivative
from plant.faults import FaultKind
from plant.interface import HEALTH_FIELDS, SUBSTEP_S, Ambient, PlantConfig
from plant.jit import JIT
from plant.periphery import ENGINE_FAULTS, PlantBase
from plant.pump import pump_flow
from plant.steady_line import running_line

_derivative = njit(**JIT)(fast_model_derivative)  # the same eq. 3.5


@njit(**JIT)
def advance_fast(x: np.ndarray, dv_volt: float, theta: tuple, n_steps: int, dt: float) -> None:
    """n_steps RK4 steps of eq. 3.24 for x = [dN %, dN' %/s] with dV held (as FastEngine.step)."""
    for _ in range(n_steps):
        x1, x2 = x[0], x[1]
        a1, b1 = _derivative(x1, x2, dv_volt, theta)
        a2, b2 = _derivative(x1 + 0.5 * dt * a1, x2 + 0.5 * dt * b1, dv_volt, theta)
        a3, b3 = _derivative(x1 + 0.5 * dt * a2, x2 + 0.5 * dt * b2, dv_volt, theta)
        a4, b4 = _derivative(x1 + dt * a3, x2 + dt * b3, dv_volt, theta)
        x[0] = x1 + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        x[1] = x2 + dt / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)


@lru_cache(maxsize=4)
def _quasi_steady(ambient: Ambient) -> dict[str, np.ndarray]:
    return running_line(make_model(ambient))


class FastPlant(PlantBase):
    """Eq. 3.24 plant; ``step`` = one ECU period of 1 ms RK4 steps."""

    def __init__(
        self, config: PlantConfig | None = None, theta: tuple[float, ...] = THETA_EQ_3_23
    ) -> None:
        config = PlantConfig() if config is None else config
        maps = default_maps()
        self._params = make_model(config.ambient).params
        super().__init__(config, maps.pump, self._params.n_max_rpm)
        self._refuse_unsupported(config.faults)
        for name in HEALTH_FIELDS:
            if getattr(config, name) != 1.0:
                raise ValueError(f"{name}: FastPlant has no compressor or turbine (aero only)")
        self.theta = tuple(float(t) for t in theta)
        self.reference_voltage = maps.trim_pump_voltage  # dV = 0 (aero-thermal trim)
        self._table = _quasi_steady(config.ambient)
        n0 = float(
            np.interp(config.initial_fuel_kg_s, self._table["fuel_kg_s"], self._table["N_pct"])
        )
        self._x = np.array([n0 - TRIM_N_PCT, 0.0])
        self._theta_eff = self.theta
        self._pump_changed()  # the pump's gain (config.pump_gain)
        t0, _, t2, t3, t4 = self.theta
        dn = self._x[0]
        self.trim_pump_voltage = float(
            self.reference_voltage - t0 * dn / (t2 + t3 * dn + t4 * dn * dn)
        )
        self.trim_duty = self._duty_for(self.trim_pump_voltage)
        self._start(self._at("EGT_K"), self.trim_duty)

    @property
    def state(self) -> np.ndarray:
        """Copy of x = [dN %, dN' %/s] (deviations from N = 89.68 %)."""
        return self._x.copy()

    def _supports(self, kind: FaultKind) -> bool:
        return kind not in ENGINE_FAULTS  # no compressor, turbine or thermodynamics here

    def _at(self, column: str) -> float:
        n = TRIM_N_PCT + float(self._x[0])
        return float(np.interp(n, self._table["N_pct"], self._table[column]))

    def _advance(self, v_pump: float) -> int:
        advance_fast(
            self._x,
            v_pump - self.reference_voltage,
            self._theta_eff,
            self.config.substeps,
            SUBSTEP_S,
        )
        return 0

    def _truth(
        self, v_pump: float
    ) -> tuple[float, float, float, float, float, float, float, float, int]:
        fuel, _ = pump_flow(
            v_pump, self._pump_outlet_gauge(), self._pump, self.delivering_effectiveness
        )
        return (
            TRIM_N_PCT + float(self._x[0]),
            self._at("P3_Pa"),
            self._at("P5_Pa"),
            self._at("T4_K"),
            self._at("EGT_K"),
            fuel,
            self._at("air_kg_s"),
            self._at("thrust_N"),
            0,
        )

    def _pump_outlet_gauge(self) -> float:
        return self._at("P3_Pa") + self._params.injector_dp_pa - self._params.p0_pa

    def _pump_changed(self) -> None:
        lam = self.delivering_effectiveness
        t = self.theta
        self._theta_eff = (t[0], t[1], t[2] * lam, t[3] * lam, t[4] * lam)
