"""Convergent nozzle (sec. 2.1.7) with choking and thrust.

Two readings of the text are made explicit here:
- eq. 2.27 uses the expansion ratio P7/P6 <= 1 (the inverse of beta_n in eq. 2.25);
- eq. 2.28 is the standard compressible flow function, exponent -(gamma+1)/(2(gamma-1)), with the
  Mach number of eq. 2.29 taken on the static exit temperature;
- the document names no temperature for the nozzle's gamma: it is taken at T6.
Near zero pressure difference the square-root law has an unbounded slope dg/dP, which makes the
jet-pipe plenum (eq. 2.22) too stiff for RK4 at 1 ms. Below PR_LINEAR (far below idle: only seen
while spooling down) flow, velocity and thrust therefore fall linearly with P6 - P0 to zero (and
reverse for P6 < P0), continuous with the compressible law at PR_LINEAR.
"""

from __future__ import annotations

import math

from numba import njit

from plant.jit import JIT
from plant.thermo import R_AIR, cp_air

PR_LINEAR = 1.03  # P6/P0 below which the nozzle law is linearised in P6 - P0


@njit(**JIT)
def _nozzle_compressible(
    p6_pa: float, t6_k: float, p0_pa: float, area_m2: float, eta_n: float
) -> tuple[float, float, float, bool]:
    """(g7, U7, P7, choked) for P6 > P0 by eqs. 2.25-2.29, gamma at T6."""
    cp6 = cp_air(t6_k)
    g = cp6 / (cp6 - R_AIR)
    e = (g - 1.0) / g
    # 2.25 against 2.26, compared as (P0/P6)^e < beta_cri^e = 2/(gamma+1): one power less
    expansion_e = (p0_pa / p6_pa) ** e
    choked = expansion_e < 2.0 / (g + 1.0)
    if choked:
        expansion_e = 2.0 / (g + 1.0)
        p7 = p6_pa * (2.0 / (g + 1.0)) ** (1.0 / e)  # 2.26
    else:
        p7 = p0_pa
    u7 = math.sqrt(2.0 * cp6 * t6_k * eta_n * (1.0 - expansion_e))  # 2.27
    t7 = t6_k - u7 * u7 / (2.0 * cp6)
    m7 = u7 / math.sqrt(g * R_AIR * t7)  # 2.29
    flow_fn = (
        math.sqrt(g / R_AIR)
        * m7
        * (1.0 + 0.5 * (g - 1.0) * m7 * m7) ** (-(g + 1.0) / (2.0 * (g - 1.0)))
    )
    g7 = area_m2 * p6_pa / math.sqrt(t6_k) * flow_fn  # 2.28
    return g7, u7, p7, choked


@njit(**JIT)
def nozzle(
    p6_pa: float, t6_k: float, p0_pa: float, u0_m_s: float, area_m2: float, eta_n: float
) -> tuple[float, float, bool]:
    """(g7, net thrust F7, choked) for jet-pipe conditions (P6, T6) = (P5, T5) (eqs. 2.23, 2.24)."""
    if p6_pa >= PR_LINEAR * p0_pa:
        g7, u7, p7, choked = _nozzle_compressible(p6_pa, t6_k, p0_pa, area_m2, eta_n)
        thrust = g7 * (u7 - u0_m_s) + area_m2 * (p7 - p0_pa)  # 2.30
        return g7, thrust, choked
    p_lin = PR_LINEAR * p0_pa
    g_lin, u_lin, _, _ = _nozzle_compressible(p_lin, t6_k, p0_pa, area_m2, eta_n)
    s = (p6_pa - p0_pa) / (p_lin - p0_pa)
    g7 = g_lin * s
    thrust = g7 * (u_lin * abs(s) - u0_m_s)  # 2.30 with the linearised jet speed
    return g7, thrust, False
