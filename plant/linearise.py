"""The aero-thermal engine linearised about a steady state with the gear pump in the loop: its
poles, and the shaft's time constant and speed gain per pump volt, the figures a first-order fit
(appendix B) and a second-order fit (eq. 3.1, 3.23) of the engine should find.

    dx/dt = A dx + b dV,   x = [P3, P5, T4, N],   V the pump voltage
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from plant.engine import EngineModel, engine_rates, pump_fuel_flow
from plant.trim import SteadyState, solve_steady

STEP = np.array([1e3, 1e3, 1.0, 0.01])  # central differences: Pa, Pa, K, %N
STEP_V = 0.01  # V


class Linearisation(NamedTuple):
    poles: np.ndarray  # eigenvalues of A, 1/s, slowest first
    tau_s: float  # -1 / the slowest (real) pole
    gain_pct_per_v: float  # steady dN/dV
    pump_v: float  # the pump voltage holding the steady state


def _rates(model: EngineModel, x: np.ndarray, v_pump: float) -> np.ndarray:
    g_fuel, _ = pump_fuel_flow(x, v_pump, model)
    dxdt = np.empty(4)
    engine_rates(x, g_fuel, 1.0, model, dxdt)
    return dxdt


def pump_voltage_for(model: EngineModel, x: np.ndarray, g_fuel: float) -> float:
    """The pump voltage delivering g_fuel against the state's P3 (bisection on the table)."""
    lo, hi = 0.0, float(model.pump.voltage[-1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pump_fuel_flow(x, mid, model)[0] < g_fuel else (lo, mid)
    return 0.5 * (lo + hi)


def state_space(model: EngineModel, x: np.ndarray, v: float) -> tuple[np.ndarray, np.ndarray]:
    """A and b by central differences about the state x at pump voltage v."""
    a = np.empty((4, 4))
    for j in range(4):
        up, down = x.copy(), x.copy()
        up[j] += STEP[j]
        down[j] -= STEP[j]
        a[:, j] = (_rates(model, up, v) - _rates(model, down, v)) / (2.0 * STEP[j])
    b = (_rates(model, x, v + STEP_V) - _rates(model, x, v - STEP_V)) / (2.0 * STEP_V)
    return a, b


def speed_rate_per_volt(
    model: EngineModel, steady: SteadyState, g_fuel: float, omegas: np.ndarray
) -> np.ndarray:
    """|dN/dt / dV|, %N/s per V, at the angular frequencies omegas (rad/s): the fuel reaches
    the turbine's torque within milliseconds, so the shaft's rate answers a pump step at once
    (a first-order shaft, relative degree one) and this stays flat far above the shaft's pole."""
    a, b = state_space(model, steady.x, pump_voltage_for(model, steady.x, g_fuel))
    return np.array([abs(1j * w * np.linalg.solve(1j * w * np.eye(4) - a, b)[3]) for w in omegas])


def linearise(model: EngineModel, steady: SteadyState, g_fuel: float) -> Linearisation:
    """A and b by central differences about a steady state at fuel flow g_fuel."""
    x, v = steady.x, pump_voltage_for(model, steady.x, g_fuel)
    a, b = state_space(model, x, v)
    poles = np.linalg.eigvals(a)
    poles = poles[np.argsort(np.abs(poles))]
    gain = float(-np.linalg.solve(a, b)[3])
    return Linearisation(poles, float(-1.0 / poles[0].real), gain, v)


def linearise_at_speed(model: EngineModel, n_pct: float) -> Linearisation:
    """The linearisation at the steady state of speed n_pct (the fuel flow found by bisection)."""
    return linearise(model, *steady_at_speed(model, n_pct))


def steady_at_speed(model: EngineModel, n_pct: float) -> tuple[SteadyState, float]:
    """The steady state of speed n_pct and its fuel flow (bisection on the fuel flow)."""
    lo, hi = 1e-3, 0.02
    x0 = None
    for _ in range(40):
        g = 0.5 * (lo + hi)
        try:
            s = solve_steady(model, g, x0=x0, settle_s=3.0)
        except (ValueError, RuntimeError):
            lo = g  # below the running line: more fuel
            continue
        x0 = s.x
        lo, hi = (g, hi) if s.x[3] < n_pct else (lo, g)
    g = 0.5 * (lo + hi)
    return solve_steady(model, g, x0=x0, settle_s=3.0), g
