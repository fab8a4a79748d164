"""Gas properties of air: Cp from a 4th-order polynomial of temperature, gamma at a mean
temperature.

Ch. 2 keeps the air lumped: Cp(T) from a 4th-order polynomial, and each component evaluates gamma
at the arithmetic mean of its inlet and outlet temperatures (text after eqs. 2.10 and 2.20).
The coefficients fit the ideal-gas table of dry air from 250 K to 1500 K within about 1 %; outside
that band the polynomial is held at its edge value so that no temperature gives a wild Cp.
"""

from __future__ import annotations

from numba import njit

from plant.jit import JIT

R_AIR = 287.05  # J/(kg K)
T_STD_K = 288.15  # eq. 2.9 reference temperature
P_STD_PA = 101325.0  # eq. 2.9 reference pressure

# Cp = c0 + c1 T + c2 T^2 + c3 T^3 + c4 T^4  [J/(kg K)], T in K
CP_COEFFS = (1.0575e3, -0.4489, 1.1407e-3, -0.7999e-6, 0.1933e-9)
CP_T_MIN_K = 200.0
CP_T_MAX_K = 1600.0


@njit(**JIT)
def cp_air(t_k: float) -> float:
    """Cp of air at temperature t_k (Horner form of the 4th-order polynomial)."""
    c0, c1, c2, c3, c4 = CP_COEFFS
    t_k = min(max(t_k, CP_T_MIN_K), CP_T_MAX_K)
    return c0 + t_k * (c1 + t_k * (c2 + t_k * (c3 + t_k * c4)))


@njit(**JIT)
def gamma_air(t_k: float) -> float:
    """gamma = Cp / (Cp - R) at temperature t_k."""
    cp = cp_air(t_k)
    return cp / (cp - R_AIR)


@njit(**JIT)
def gamma_mean(t_in_k: float, t_out_k: float) -> float:
    """gamma at the arithmetic mean of a component's inlet and outlet temperatures."""
    return gamma_air(0.5 * (t_in_k + t_out_k))
