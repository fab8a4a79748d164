"""The document's staircase experiment (secs. 2.3.2 and 3.3): from the trim, steps to 83, 90, 94
and 97 %N and back down through the same levels, by fuel flow (figs. 2.14-2.17) or by pump voltage
(fig. 3.2, the data of the least squares of eq. 3.22)."""

from __future__ import annotations

import numpy as np

from plant.engine import EngineModel, advance
from plant.pump import pump_flow
from plant.trim import solve_steady

LEVELS_PCT = (83.0, 90.0, 94.0, 97.0, 94.0, 90.0, 83.0)
DT_S = 0.001


def steady_fuel_for(table: dict[str, np.ndarray], n_pct: float) -> float:
    """Fuel flow of the running line at n_pct (running-line table from plant.steady_line)."""
    return float(np.interp(n_pct, table["N_pct"], table["fuel_kg_s"]))


def steady_voltage_for(model: EngineModel, table: dict[str, np.ndarray], n_pct: float) -> float:
    """Pump voltage holding the engine at n_pct: the running-line fuel against its P3."""
    g_fuel = steady_fuel_for(table, n_pct)
    s = solve_steady(model, g_fuel)
    p = model.params
    p_out = s.x[0] + p.injector_dp_pa - p.p0_pa
    lo, hi = 0.0, float(model.pump.voltage[-1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        q, _ = pump_flow(mid, p_out, model.pump, p.pump_effectiveness)
        lo, hi = (mid, hi) if q < g_fuel else (lo, mid)
    return 0.5 * (lo + hi)


def run(
    model: EngineModel, x0: np.ndarray, inputs: list[float], hold_s: float, pump_in_loop: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hold each input for hold_s from state x0; (time s, states [k, 4], input) every 1 ms."""
    n_hold = int(round(hold_s / DT_S))
    x = np.array(x0, dtype=float)
    work = np.empty((5, 4))
    states = np.empty((n_hold * len(inputs), 4))
    u = np.repeat(np.asarray(inputs, dtype=float), n_hold)
    lit = 1.0
    for k in range(u.size):
        _, lit = advance(x, u[k], pump_in_loop, lit, 1, DT_S, model, work)
        states[k] = x
    return np.arange(1, u.size + 1) * DT_S, states, u


def plot(t: np.ndarray, states: np.ndarray, fuel: np.ndarray, path: str) -> None:
    """The four states against time, like the document's figs. 2.14-2.17."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(5, 1, figsize=(8, 10), sharex=True)
    series = [
        (fuel * 1e3, "fuel flow, g/s"),
        (states[:, 0] / 1e5, "P3, bar (fig. 2.14)"),
        (states[:, 1] / 1e5, "P5, bar (fig. 2.15)"),
        (states[:, 2], "T4, K (fig. 2.16)"),
        (states[:, 3], "N, % (fig. 2.17)"),
    ]
    for a, (y, label) in zip(ax, series, strict=True):
        a.plot(t, y, "b-", lw=1)
        a.set_ylabel(label, fontsize=8)
        a.grid(alpha=0.3)
    ax[-1].set_xlabel("time, s")
    ax[0].set_title("fuel staircase 83 / 90 / 94 / 97 %N and back (secs. 2.3.2, 3.3)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
