"""Shaft dynamics (sec. 2.1.8): angular momentum balance with a mechanical efficiency."""

from __future__ import annotations

from numba import njit

from plant.jit import JIT

OMEGA_MIN_RAD_S = 50.0  # floor of the speed in the denominator of eq. 2.31 (about 0.4 % N_max)


@njit(**JIT)
def shaft_domega_dt(
    omega_rad_s: float, power_turbine: float, power_compressor: float, eta_m: float, inertia: float
) -> float:
    """dN/dt in rad/s^2 (eq. 2.31); a stopped rotor does not turn backwards."""
    domega = (eta_m * power_turbine - power_compressor) / (
        inertia * max(omega_rad_s, OMEGA_MIN_RAD_S)
    )
    if omega_rad_s <= 0.0 and domega < 0.0:
        return 0.0
    return domega
