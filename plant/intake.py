"""Intake (sec. 2.1.1): ideal, so the flight speed only adds ram compression."""

from __future__ import annotations

import math

from numba import njit

from plant.jit import JIT
from plant.thermo import R_AIR, gamma_air, gamma_mean


@njit(**JIT)
def intake(p0_pa: float, t0_k: float, u0_m_s: float) -> tuple[float, float]:
    """Stagnation (P2, T2) at the intake outlet from ambient (P0, T0) and flight speed U0."""
    p1, t1 = p0_pa, t0_k  # 2.3, 2.4
    m0 = u0_m_s / math.sqrt(gamma_air(t0_k) * R_AIR * t0_k)
    t2 = t1
    for _ in range(2):  # gamma at the mean of T1 and T2, one fixed-point pass
        g = gamma_mean(t1, t2)
        t2 = t1 * (1.0 + 0.5 * (g - 1.0) * m0 * m0)  # 2.6
    g = gamma_mean(t1, t2)
    p2 = p1 * (t2 / t1) ** (g / (g - 1.0))  # 2.5
    return p2, t2
