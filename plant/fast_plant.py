"""The fast engine model of eq. 3.24 as a second plant with the interface of plant/interface.py.

Shaft dynamics from eq. 3.24 (deviations from the trim N = 89.68 %, V = the aero-thermal trim
pump voltage); pump driver, battery and sensors as in the aero-thermal plant. What the fast model
does not have (P3, P5, T4, EGT, thrust, air flow) is read off the aero-thermal running line at
the present speed, quasi-steadily. Pump effectiveness scales the input terms theta2..theta4, as
the document's failure does (sec. 4.2, ch. 6); a dry or stalled pump is effectiveness 0, which in
this model means "no response to the voltage", not a flameout. Compressor and turbine health
and ambient faults have no counterpart here and are refused. One period is one compiled call,
``fast_period`` (see plant/periphery.py).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from plant import flags as fl
from plant.aerothermal import default_maps, make_model
from plant.fast_model import THETA_EQ_3_23, TRIM_N_PCT, fast_model_derivative
from plant.faults import FaultKind
from plant.interface import HEALTH_FIELDS, SUBSTEP_S, Ambient, PlantConfig
from plant.jit import EXACT, JIT
from plant.periphery import (
    ENGINE,
    ENGINE_FAULTS,
    PlantBase,
    delivering,
    pack_tables,
    publish,
    pump_driver,
    pump_health,
    pump_table_at,
    pump_tables,
    vec,
)
from plant.pump import pump_flow
from plant.steady_line import running_line

_derivative = njit(**JIT)(fast_model_derivative)  # the same eq. 3.5
_pump_flow = njit(**JIT)(pump_flow.py_func)  # pump_flow as Python calls it, not inlined

# the fast plant's part of the state array: x, theta, theta with the pump's effectiveness,
# reference voltage, injector pressure drop, ambient pressure, substeps
X = ENGINE
THETA = X + 2
THETA_EFF = THETA + 5
REFERENCE_V = THETA_EFF + 5
INJECTOR_DP = REFERENCE_V + 1
P0 = INJECTOR_DP + 1
N_SUB = P0 + 1
# the running line's columns read off at the present speed (tables 0..6; the pump's are 7..9)
LINE = ("N_pct", "P3_Pa", "P5_Pa", "T4_K", "EGT_K", "air_kg_s", "thrust_N")


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


@njit(**EXACT, inline="always")
def _locate(xp: np.ndarray, x: float) -> int:
    """numpy.interp's index: -1 below xp, len(xp) above, else the last j with xp[j] <= x."""
    n = xp.shape[0]
    if x < xp[0]:
        return -1
    if x > xp[n - 1]:
        return n
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if xp[mid] <= x:
            lo = mid
        else:
            hi = mid
    return hi if xp[hi] <= x else lo


@njit(**EXACT, inline="always")
def _interp_at(x: float, j: int, xp: np.ndarray, fp: np.ndarray) -> float:
    """numpy.interp(x, xp, fp) with j = _locate(xp, x), as numpy computes it."""
    n = xp.shape[0]
    if j == -1:
        return fp[0]
    if j >= n - 1:
        return fp[n - 1]
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    r = slope * (x - xp[j]) + fp[j]
    if np.isnan(r):
        r = slope * (x - xp[j + 1]) + fp[j + 1]
        if np.isnan(r) and fp[j] == fp[j + 1]:
            r = fp[j]
    return r


@njit(**EXACT, inline="always")
def _theta_changed(s: np.ndarray) -> None:
    lam = delivering(s)
    s[THETA_EFF], s[THETA_EFF + 1] = s[THETA], s[THETA + 1]
    for i in range(2, 5):
        s[THETA_EFF + i] = s[THETA + i] * lam


@njit(**EXACT)
def fast_period(
    s: np.ndarray, t: np.ndarray, u: float, pump_enabled: bool, tick: int, pump_in_loop: bool
) -> int:
    """One ECU period of the fast plant on its state array s and tables t: pump wear, driver
    and battery at duty u, eq. 3.24 (advance_fast), the running line at the new speed, limits
    and sensors into s. Returns the flags. The pump is always in the loop here: pump_in_loop is
    there for the kernels' common signature (PlantBase._period_with calls either plant's kernel
    with it; aero_period's fuel-commanded periods pass False), and is not read."""
    if pump_health(s):
        _theta_changed(s)
    n_axis = vec(t, 0)
    x = s[X : X + 2]
    n_pct = TRIM_N_PCT + x[0]
    p3 = _interp_at(n_pct, _locate(n_axis, n_pct), n_axis, vec(t, 1))
    supply, v_pump, current = pump_driver(s, u, p3 + s[INJECTOR_DP] - s[P0])
    e = THETA_EFF
    theta = (s[e], s[e + 1], s[e + 2], s[e + 3], s[e + 4])
    advance_fast(x, v_pump - s[REFERENCE_V], theta, int(s[N_SUB]), SUBSTEP_S)
    flags = 0 if pump_enabled else fl.PUMP_UNPOWERED
    n_pct = TRIM_N_PCT + x[0]
    j = _locate(n_axis, n_pct)
    p3 = _interp_at(n_pct, j, n_axis, vec(t, 1))
    p5 = _interp_at(n_pct, j, n_axis, vec(t, 2))
    t4 = _interp_at(n_pct, j, n_axis, vec(t, 3))
    egt = _interp_at(n_pct, j, n_axis, vec(t, 4))
    air = _interp_at(n_pct, j, n_axis, vec(t, 5))
    thrust = _interp_at(n_pct, j, n_axis, vec(t, 6))
    p_out = p3 + s[INJECTOR_DP] - s[P0]
    fuel, _ = _pump_flow(v_pump, p_out, pump_table_at(t, 7, s), delivering(s))
    return publish(
        s, tick, flags, supply, v_pump, current, n_pct, p3, p5, t4, egt, fuel, air, thrust,
        0.0, egt, 0.0, 1.0,
    )  # fmt: skip


@lru_cache(maxsize=4)
def _quasi_steady(ambient: Ambient) -> dict[str, np.ndarray]:
    return running_line(make_model(ambient))


class FastPlant(PlantBase):
    """Eq. 3.24 plant; ``step`` = one ECU period of 1 ms RK4 steps."""

    ENGINE_SLOTS = N_SUB + 1 - ENGINE
    KERNEL = staticmethod(fast_period)

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
        if config.standstill:
            raise ValueError("standstill: FastPlant models a running engine only (aero only)")
        self.theta = tuple(float(t) for t in theta)
        self.reference_voltage = maps.trim_pump_voltage  # dV = 0 (aero-thermal trim)
        self._table = _quasi_steady(config.ambient)
        self._tables = pack_tables([self._table[c] for c in LINE] + pump_tables(maps.pump))
        n0 = float(
            np.interp(config.initial_fuel_kg_s, self._table["fuel_kg_s"], self._table["N_pct"])
        )
        if config.initial_speed_pct is not None:  # EGT rises with speed along the line
            hottest = float(
                np.interp(config.initial_egt_max_k, self._table["EGT_K"], self._table["N_pct"])
            )
            n0 = min(config.initial_speed_pct, hottest)
        s = self._s
        s[X : X + 2] = (n0 - TRIM_N_PCT, 0.0)
        s[THETA:THETA_EFF] = self.theta
        s[REFERENCE_V] = self.reference_voltage
        s[INJECTOR_DP], s[P0] = self._params.injector_dp_pa, self._params.p0_pa
        s[N_SUB] = config.substeps
        self._pump_changed()  # the pump's gain (config.pump_gain)
        t0, _, t2, t3, t4 = self.theta
        dn = s[X]
        self.trim_pump_voltage = float(
            self.reference_voltage - t0 * dn / (t2 + t3 * dn + t4 * dn * dn)
        )
        self.trim_duty = self._duty_for(self.trim_pump_voltage)
        self._start(self._at("EGT_K"), self.trim_duty)

    @property
    def state(self) -> np.ndarray:
        """Copy of x = [dN %, dN' %/s] (deviations from N = 89.68 %)."""
        return self._s[X : X + 2].copy()

    def _supports(self, kind: FaultKind) -> bool:
        return kind not in ENGINE_FAULTS  # no compressor, turbine or thermodynamics here

    def _at(self, column: str) -> float:
        n = TRIM_N_PCT + float(self._s[X])
        return float(np.interp(n, self._table["N_pct"], self._table[column]))

    def _truth(self, v_pump: float) -> tuple:
        fuel, _ = pump_flow(
            v_pump, self._pump_outlet_gauge(), self._pump, self.delivering_effectiveness
        )
        return (
            TRIM_N_PCT + float(self._s[X]),
            self._at("P3_Pa"),
            self._at("P5_Pa"),
            self._at("T4_K"),
            self._at("EGT_K"),
            fuel,
            self._at("air_kg_s"),
            self._at("thrust_N"),
            0,
            self._at("EGT_K"),
            0.0,
            1.0,
        )

    def _pump_outlet_gauge(self) -> float:
        return self._at("P3_Pa") + self._params.injector_dp_pa - self._params.p0_pa

    def _pump_changed(self) -> None:
        lam = self.delivering_effectiveness
        t = self.theta
        self._s[THETA_EFF:REFERENCE_V] = (t[0], t[1], t[2] * lam, t[3] * lam, t[4] * lam)
