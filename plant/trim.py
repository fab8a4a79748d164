"""Steady states of the aero-thermal engine: trim at a fuel flow, and the running line.

A steady state is found by letting the engine settle (the model is stable on its running line)
and polishing with Newton's method on dx/dt = 0 in scaled variables.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from plant.engine import EngineModel, Stations, advance_fuel, engine_rates, stations
from plant.flags import LEAN_LIMIT

SCALE = np.array([1e5, 1e5, 1e3, 100.0])  # Pa, Pa, K, %N
TRIM_GUESS = np.array([294845.0, 162676.0, 1159.0, 89.68])  # eq. 2.32
TRIM_FUEL_KG_S = 0.008  # eq. 2.32's fuel flow
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
    model: EngineModel,
    g_fuel: float,
    x0: np.ndarray | None = None,
    settle_s: float = 10.0,
    tolerance: float = 1e-6,
) -> SteadyState:
    """Steady state at fuel flow g_fuel (kg/s), starting from x0 (default: the eq. 2.32 trim),
    to within ``tolerance`` of every scaled rate (1/s)."""
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
    if not residual <= tolerance:  # also catches NaN
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


def solve_steady_at_speed(
    model: EngineModel, n_pct: float, egt_max_k: float = np.inf
) -> tuple[float, SteadyState]:
    """Fuel flow and steady state holding speed n_pct, or, where that EGT would exceed
    egt_max_k, the fastest steady state within it: the point a governor with that EGT limit
    holds. Speed and EGT both rise with fuel along the running line, so the point is the root in
    the fuel flow of max(N - n_pct, (EGT - egt_max_k) / 10 K), bracketed by walking the line from
    the eq. 2.32 trim in FUEL_STEP_KG_S steps (continuation) and found by the Illinois method. An
    engine whose EGT has a minimum above egt_max_k starts at that minimum, one that runs no
    slower than n_pct at its slowest steady state."""
    if not np.isfinite(n_pct) or not MIN_RUNNING_N_PCT < n_pct <= 120.0:
        raise ValueError(f"speed must be in ({MIN_RUNNING_N_PCT:g}, 120] %N, got {n_pct!r}")
    if not egt_max_k > 0.0:
        raise ValueError(f"EGT limit must be positive (K), got {egt_max_k!r}")

    def f(s: SteadyState) -> float:
        return max(s.x[3] - n_pct, (s.stations.t5 - egt_max_k) / 10.0)

    what = f"at {n_pct:g} %N" + ("" if np.isinf(egt_max_k) else f" or EGT {egt_max_k:g} K")
    return _walk_to(model, f, what)


FUEL_STEP_KG_S = 0.0005
START_TOLERANCE = 1e-4  # scaled rates of a start state: N drifts by under 0.01 %N/s


def _walk_to(
    model: EngineModel, f: Callable[[SteadyState], float], what: str
) -> tuple[float, SteadyState]:
    """Root in the fuel flow of f(steady state), which rises with fuel along the running line;
    where f turns back before its root on the way down, or the line ends (to FUEL_STEP_KG_S),
    the steady state nearest the root."""
    g, s = TRIM_FUEL_KG_S, solve_steady(model, TRIM_FUEL_KG_S)
    step = FUEL_STEP_KG_S if f(s) < 0.0 else -FUEL_STEP_KG_S
    while True:
        try:
            nxt = solve_steady(model, g + step, x0=s.x, settle_s=5.0)
        except (ValueError, RuntimeError):
            if step < 0.0:  # the engine runs no slower: its slowest steady state
                return g, s
            raise ValueError(
                f"no steady state {what}: the running line ends at {g * 1e3:.1f} g/s "
                f"({s.x[3]:.1f} %N, EGT {s.stations.t5:.0f} K)"
            ) from None
        if (f(nxt) >= 0.0) == (step > 0.0):
            break
        if step < 0.0 and f(nxt) >= f(s):
            return g, s
        g, s = g + step, nxt
        if not 0.0 < g + step < 0.05:
            raise ValueError(f"no steady state {what} below 50 g/s")
    lo, hi = sorted((g, g + step))
    states = {g: s, g + step: nxt}  # the bracket's ends

    def at(g: float) -> SteadyState:
        if g not in states:  # (a start: steady to 0.01 %N/s where the maps' kinks stop Newton)
            for end in (lo, hi):  # settled from either end of the bracket
                try:
                    states[g] = solve_steady(
                        model, g, x0=states[end].x, settle_s=5.0, tolerance=START_TOLERANCE
                    )
                    break
                except (ValueError, RuntimeError):
                    continue
            else:
                raise _Unsettled
        return states[g]

    try:
        root = _illinois(lambda g: f(at(g)), lo, hi)
    except _Unsettled:  # a point inside the bracket settled from neither end: its nearer end
        root = min((lo, hi), key=lambda g: abs(f(states[g])))
    return root, at(root)


class _Unsettled(Exception):
    """No steady state settled at a fuel flow inside a bracket of two steady ones."""


def _illinois(
    f: Callable[[float], float], a: float, b: float, xtol: float = 1e-12, iterations: int = 60
) -> float:
    """Root of f in [a, b], f(a) < 0 < f(b): regula falsi with the Illinois halving (scipy's
    root finders are not used here: the plant node starts without scipy.linalg)."""
    fa, fb = f(a), f(b)
    side = 0
    for _ in range(iterations):
        c = (a * fb - b * fa) / (fb - fa)
        fc = f(c)
        if fc == 0.0 or b - a < xtol:
            return c
        if fc < 0.0:
            a, fa = c, fc
            if side == -1:
                fb *= 0.5
            side = -1
        else:
            b, fb = c, fc
            if side == 1:
                fa *= 0.5
            side = 1
    return c


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
