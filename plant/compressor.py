"""Compressor (sec. 2.1.2): volumeless, quasi-steady, two map lookups.

Below a pressure ratio of 1 (a windmilling rotor with air pulled through it) the compressor does
no work and the air is throttled at constant temperature.
Health parameters scale the map outputs as in NASA's C-MAPSS/T-MATS engine models: a flow scalar
on the corrected flow and an efficiency scalar on the isentropic efficiency (1.0 = new engine).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from plant.flags import COMPRESSOR_MAP_CLAMPED, SURGE
from plant.jit import JIT
from plant.lookup import interp1, interp2
from plant.thermo import P_STD_PA, T_STD_K, cp_air, gamma_mean

ETA_MIN = 0.05  # floor on the scaled efficiency, keeps eq. 2.10 finite at any health value
SURGE_MIN_N_PCT = 10.0  # below this corrected speed a stopped rotor is not said to surge


class CompressorMap(NamedTuple):
    """Tables of eqs. 2.7 and 2.8 (corrected speed in % of N_max)."""

    beta: np.ndarray  # pressure-ratio axis of the flow table
    n_cor_pct: np.ndarray  # corrected-speed axis of both tables
    flow: np.ndarray  # corrected flow [beta, n_cor], kg/s
    flow_axis: np.ndarray  # corrected-flow axis of the efficiency table, kg/s
    efficiency: np.ndarray  # isentropic efficiency [flow_axis, n_cor]
    surge_beta: np.ndarray  # surge-line pressure ratio at each n_cor


@njit(**JIT, inline="always")
def compressor(
    p2_pa: float,
    t2_k: float,
    p3_pa: float,
    n_pct: float,
    cmap: CompressorMap,
    flow_scale: float,
    eff_scale: float,
) -> tuple[float, float, float, int]:
    """(g2, T3, absorbed power, flags) for inlet (P2, T2), delivery pressure P3 and speed N."""
    theta = t2_k / T_STD_K  # 2.9
    delta = p2_pa / P_STD_PA
    n_cor = n_pct / math.sqrt(theta)
    beta = p3_pa / p2_pa
    flags = 0
    g_cor, out1 = interp2(cmap.beta, cmap.n_cor_pct, cmap.flow, beta, n_cor)  # 2.7
    g_cor *= flow_scale
    eta, out2 = interp2(cmap.flow_axis, cmap.n_cor_pct, cmap.efficiency, g_cor, n_cor)  # 2.8
    eta = max(eta * eff_scale, ETA_MIN)
    surge_beta, _ = interp1(cmap.n_cor_pct, cmap.surge_beta, n_cor)
    if out1 or out2:
        flags |= COMPRESSOR_MAP_CLAMPED
    if beta > surge_beta and n_cor > SURGE_MIN_N_PCT:
        flags |= SURGE
    g2 = g_cor * delta / math.sqrt(theta)
    t3 = t2_k
    ln_beta = math.log(beta)
    for _ in range(2):  # gamma at the mean of T2 and T2p, one fixed-point pass
        g = gamma_mean(t2_k, t3)
        t3 = t2_k * (1.0 + max(math.expm1(ln_beta * (g - 1.0) / g), 0.0) / eta)  # 2.10
    power = g2 * (cp_air(t3) * t3 - cp_air(t2_k) * t2_k)  # 2.11, absorbed power > 0
    return g2, t3, power, flags


def surge_margin(
    cmap: CompressorMap, p2_pa: float, t2_k: float, p3_pa: np.ndarray, n_pct: np.ndarray
) -> np.ndarray:
    """Surge margin: the surge line's pressure ratio at the corrected speed over the working
    pressure ratio P3/P2, less one (0 on the surge line, negative beyond it); arrays welcome."""
    n_cor = np.asarray(n_pct, dtype=float) / math.sqrt(t2_k / T_STD_K)  # 2.9
    surge_beta = np.interp(n_cor, cmap.n_cor_pct, cmap.surge_beta)  # clamped as interp1
    return surge_beta / (np.asarray(p3_pa, dtype=float) / p2_pa) - 1.0
