"""Burner (sec. 2.1.4): a pure energy accumulator with a time constant and a pressure loss.

The fuel arrives at ambient temperature. Heat release stops when the flame is out (lit = 0) and
cannot exceed what the air can burn (stoichiometric fuel-air ratio), which keeps the energy
balance finite when almost no air passes.
"""

from __future__ import annotations

from numba import njit

from plant.jit import JIT
from plant.thermo import cp_air

FAR_STOICHIOMETRIC = 0.068  # kerosene / JP8 in air
G4_MIN_KG_S = 0.005  # floor of g4 in the denominator of eq. 2.15 (a stopped flow freezes T4)


@njit(**JIT)
def burner(
    p3_pa: float,
    t3_k: float,
    g3: float,
    t4_k: float,
    g4: float,
    g_fuel: float,
    t_fuel_k: float,
    lit: float,
    eta_loss: float,
    eta_b: float,
    lhv: float,
    cp_fuel: float,
    tau_b: float,
) -> tuple[float, float]:
    """(P4, dT4/dt) from the burner inlet and outlet flows and the fuel flow."""
    p4 = eta_loss * p3_pa  # 2.17
    burnt = min(g_fuel, FAR_STOICHIOMETRIC * max(g3, 0.0))
    heat = g_fuel * cp_fuel * t_fuel_k + lit * eta_b * lhv * burnt
    g_out = max(g4, G4_MIN_KG_S)
    cp4 = cp_air(t4_k)
    dt4 = (g3 * cp_air(t3_k) * t3_k + heat - g4 * cp4 * t4_k) / (tau_b * g_out * cp4)  # 2.15
    return p4, dt4
