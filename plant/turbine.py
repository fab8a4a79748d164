"""Turbine (sec. 2.1.5): volumeless, quasi-steady, two map lookups against expansion ratio and
N/sqrt(T4). Below an expansion ratio of 1 it extracts no work (its flow table is zero there).
Health parameters scale flow capacity and efficiency as for the compressor."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from plant.flags import TURBINE_MAP_CLAMPED
from plant.jit import JIT
from plant.lookup import interp2_at, locate
from plant.thermo import cp_air, gamma_mean

ETA_MIN = 0.05


class TurbineMap(NamedTuple):
    """Tables of eqs. 2.18 and 2.19."""

    beta: np.ndarray  # expansion-ratio axis P4/P5
    n_t: np.ndarray  # N/sqrt(T4) axis, rpm/sqrt(K)
    flow: np.ndarray  # non-dimensional flow g4 sqrt(T4)/P4 [beta, n_t], kg sqrt(K)/(s Pa)
    efficiency: np.ndarray  # isentropic efficiency [beta, n_t]


@njit(**JIT, inline="always")
def turbine(
    p4_pa: float,
    t4_k: float,
    p5_pa: float,
    n_rpm: float,
    tmap: TurbineMap,
    flow_scale: float,
    eff_scale: float,
) -> tuple[float, float, float, int]:
    """(g4, T5, delivered power, flags) for inlet (P4, T4), outlet pressure P5 and speed N."""
    beta = p4_pa / p5_pa
    n_t = n_rpm / math.sqrt(t4_k)
    i, wx, out1 = locate(tmap.beta, beta)  # both tables share their axes
    j, wy, out2 = locate(tmap.n_t, n_t)
    phi = interp2_at(tmap.flow, i, wx, j, wy) * flow_scale  # 2.18
    eta = max(interp2_at(tmap.efficiency, i, wx, j, wy) * eff_scale, ETA_MIN)  # 2.19
    flags = TURBINE_MAP_CLAMPED if (out1 or out2) else 0
    g4 = phi * p4_pa / math.sqrt(t4_k)
    t5 = t4_k
    ln_beta = math.log(beta)
    for _ in range(2):  # gamma at the mean of T4 and T5, one fixed-point pass
        g = gamma_mean(t4_k, t5)
        t5 = t4_k * (1.0 + eta * min(math.expm1(-ln_beta * (g - 1.0) / g), 0.0))  # 2.20
    power = g4 * (cp_air(t4_k) * t4_k - cp_air(t5) * t5)  # 2.21, delivered power > 0
    return g4, t5, power, flags
