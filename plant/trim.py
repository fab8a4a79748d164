"""Steady states of the aero-thermal engine: trim at a fuel flow, and the running line.

A steady state is found by letting the engine settle (the model is stable on its running line)
and polishing with Newton's method on dx/dt = 0 in scaled variables.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from plant.engine import EngineModel, Stations, advance_fuel, engine_rates, stations
from plant.flags import LEAN_LIMIT

SCALE = np.array([1e5, 1e5, 1e3, 100.0])  # Pa, Pa, K, %N
TRIM_GUESS = np.array([294845.0, 162676.0, 1159.0, 89.68])  # eq. 2.32
DT_S = 0.001
MIN_RUNNING_N_PCT = 10.0
DECELERATING_PCT_S = 0.1  # %N/s: still decelerating after settling, no steady state near


class SteadyState(NamedTuple):
    x: np.ndarray  # [P3 Pa, P5 Pa, T4 K, N %]
    stations: Stations
    residual: float  # max |dx/dt| / SCALE, 1/s


def _stopped(x: np.ndarray) -> bool:
    """True for a stopped engine (below MIN_RUNNING_N_PCT), which is no operating point."""
    return bool(x[3] < MIN_RUNNING_N_PCT)


def _rates(model: EngineModel, g_fuel: float, x: np.ndarray) -> np.ndarray:
    dxdt = np.empty(4)
    engine_rates(x, g_fuel, 1.0, model, dxdt)
    return dxdt


def _newton(model: EngineModel, g_fuel: float, x: np.ndarray, iterations: int = 12) -> np.ndarray:
    x = x.copy()
    for _ in range(iterations):
        f = _rates(model, g_fuel, x) / SCALE
        if np.max(np.abs(f)) < 1e-11:
            break
        jac = np.empty((4, 4))
        for j in range(4):
            h = 1e-6 * SCALE[j]
            xp = x.copy()
            xp[j] += h
            jac[:, j] = (_rates(model, g_fuel, xp) / SCALE - f) / (h / SCALE[j])
        try:
            x = x - np.linalg.solve(jac, f) * SCALE
        except np.linalg.LinAlgError:
            break
    return x


def solve_steady(
    model: EngineModel, g_fuel: float, x0: np.ndarray | None = None, settle_s: float = 10.0
) -> SteadyState:
    """Steady state at fuel flow g_fuel (kg/s), starting from x0 (default: the eq. 2.32 trim)."""
    if not np.isfinite(g_fuel) or g_fuel <= 0.0:
        raise ValueError(f"fuel flow must be a positive finite number in kg/s, got {g_fuel!r}")
    x = (TRIM_GUESS if x0 is None else np.asarray(x0, dtype=float)).copy()
    work = np.empty((5, 4))
    # settle without the lean limit: a steady state is wanted, not the transient on the way
    burning = model._replace(params=model.params._replace(far_lean=0.0))
    advance_fuel(x, g_fuel, 1.0, int(settle_s / DT_S), DT_S, burning, work)
    settled = x.copy()
    x = _newton(model, g_fuel, x)
    residual = float(np.max(np.abs(_rates(model, g_fuel, x) / SCALE)))
    st = Stations(*stations(x, g_fuel, model))
    if not residual <= 1e-6:  # also catches NaN
        if _rates(model, g_fuel, settled)[3] < -DECELERATING_PCT_S:
            raise ValueError(
                f"fuel flow {g_fuel * 1e3:.2f} g/s keeps no running engine (after {settle_s:g} s "
                f"it still decelerates through N = {settled[3]:.1f} %, below its lowest steady "
                "state)"
            )
        raise RuntimeError(f"no steady state found at {g_fuel * 1e3:.2f} g/s (residual {residual})")
    if _stopped(x):
        raise ValueError(
            f"fuel flow {g_fuel * 1e3:.2f} g/s keeps no running engine (it stops: N = {x[3]:.1f} %)"
        )
    if st.flags & LEAN_LIMIT:
        raise ValueError(
            f"fuel flow {g_fuel * 1e3:.2f} g/s is below the lean limit: the engine flames out"
        )
    return SteadyState(x=x, stations=st, residual=residual)


def steady_line(
    model: EngineModel, fuel_kg_s: np.ndarray, start: SteadyState | None = None
) -> list[SteadyState]:
    """Steady states over a rising fuel range, each started from its neighbour (continuation)."""
    out: list[SteadyState] = []
    x = None if start is None else start.x
    for g in fuel_kg_s:
        s = solve_steady(model, float(g), x0=x, settle_s=5.0)
        out.append(s)
        x = s.x
    return out


def trim_summary(model: EngineModel, g_fuel: float) -> dict[str, float]:
    """The steady state at g_fuel as the flat record `sil trim --json` prints."""
    s = solve_steady(model, g_fuel)
    st = s.stations
    n_max = model.params.n_max_rpm
    return {
        "fuel_kg_s": float(g_fuel),
        "P3_Pa": float(s.x[0]),
        "P5_Pa": float(s.x[1]),
        "T4_K": float(s.x[2]),
        "N_pct": float(s.x[3]),
        "N_rpm": float(s.x[3] * 0.01 * n_max),
        "EGT_K": float(st.t5),
        "thrust_N": float(st.thrust),
        "air_kg_s": float(st.g2),
    }
