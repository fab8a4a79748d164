"""The hot section's thermal mass: turbine wheel, nozzle guide vanes, liner and jet pipe lumped as
one metal temperature that exchanges heat with the exhaust gas downstream of the turbine.

The gas leaving the turbine at T5 meets metal at Tm and leaves the jet pipe at
T6 = T5 + eps (Tm - T5), with the exchanger effectiveness eps = 1 - exp(-NTU),
NTU = hA / (g cp). The conductance hA is taken constant: the laminar limit, where the Nusselt
number no longer depends on the flow (the regime of a spooling-down or starter-driven engine,
where the metal matters); at running flows it gives NTU of 0.06-0.2. The metal takes what the
gas gives: C dTm/dt = -g cp (T6 - T5). Its loss to the surroundings through the casing (a few W
against kW through the engine) is neglected, so in any steady state the metal sits at the gas
temperature and T6 = T5: the steady states, the trim and the running line are the document's.

Where it shows: the exhaust gas temperature that a thermocouple in the jet pipe reads cools with
the metal after a fuel cut (in tens of seconds with the starter blowing air through, far slower
once the rotor has stopped), and lags the gas a little in a transient.
"""

from __future__ import annotations

import math

from numba import njit

from plant.jit import JIT

HEAT_CAPACITY_J_K = 300.0  # about 0.65 kg of nickel alloy and steel
CONDUCTANCE_W_K = 20.0
IN_EQUILIBRIUM = -1.0  # a metal temperature below zero: metal at the gas temperature (steady)


@njit(**JIT, inline="always")
def effectiveness(g_kg_s: float, cp: float, conductance_w_k: float) -> float:
    """eps = 1 - exp(-hA / (g cp)); 1 with no flow (the gas still there is at the metal's)."""
    if g_kg_s <= 0.0:
        return 1.0
    return -math.expm1(-conductance_w_k / (g_kg_s * cp))


@njit(**JIT, inline="always")
def gas_out(t5_k: float, t_metal_k: float, eps: float) -> float:
    """T6: the gas leaving the hot section (T5 when the metal is IN_EQUILIBRIUM)."""
    if t_metal_k < 0.0:
        return t5_k
    return t5_k + eps * (t_metal_k - t5_k)


@njit(**JIT, inline="always")
def metal_rate(g_kg_s: float, cp: float, t5_k: float, t6_k: float, capacity_j_k: float) -> float:
    """dTm/dt, K/s: the heat the gas took from the metal, g cp (T6 - T5), out of it."""
    return -max(g_kg_s, 0.0) * cp * (t6_k - t5_k) / capacity_j_k
