"""Plenums (secs. 2.1.3 and 2.1.6): unsteady mass balance between volumeless components."""

from __future__ import annotations

from numba import njit

from plant.jit import JIT
from plant.thermo import R_AIR


@njit(**JIT)
def plenum_dp_dt(t_k: float, volume_m3: float, g_in: float, g_out: float) -> float:
    """dP/dt of a plenum at temperature t_k (eqs. 2.12 and 2.22)."""
    return R_AIR * t_k / volume_m3 * (g_in - g_out)
