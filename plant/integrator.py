"""Fixed-step classical Runge-Kutta (ODE4), knowing nothing about engines.

The caller owns the derivative: for each of the four stages it evaluates dx/dt at
``rk4_stage_point`` into ``work[stage]``, then ``rk4_combine`` advances x in place. ``work`` is a
preallocated (5, n) array (four slopes and the stage point), so a step allocates nothing. (Passing
the derivative function itself into compiled code would stop numba from caching the caller.)
"""

from __future__ import annotations

import numpy as np
from numba import njit

from plant.jit import JIT

STAGES = 4
_STAGE_FRACTION = (0.0, 0.5, 0.5, 1.0)  # where each stage evaluates, in steps from x


@njit(**JIT, inline="always")
def rk4_stage_point(x: np.ndarray, stage: int, dt: float, work: np.ndarray) -> np.ndarray:
    """The state at which stage ``stage`` (0..3) evaluates the derivative (work[4], reused)."""
    xt = work[4]
    if stage == 0:
        for i in range(x.shape[0]):
            xt[i] = x[i]
    else:
        h = _STAGE_FRACTION[stage] * dt
        prev = work[stage - 1]
        for i in range(x.shape[0]):
            xt[i] = x[i] + h * prev[i]
    return xt


@njit(**JIT, inline="always")
def rk4_combine(x: np.ndarray, dt: float, work: np.ndarray) -> None:
    """x += dt/6 (k1 + 2 k2 + 2 k3 + k4) with the slopes in work[0..3]."""
    for i in range(x.shape[0]):
        x[i] += dt / 6.0 * (work[0, i] + 2.0 * work[1, i] + 2.0 * work[2, i] + work[3, i])
