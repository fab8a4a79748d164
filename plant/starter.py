"""Electric starter: a brushed DC motor on the ECU's battery, PWM-driven, geared to the rotor
through a one-way (overrunning) clutch.

Referred to the rotor, the motor is an EMF constant k and a winding resistance R: at a mean
terminal voltage v = duty x supply, its current is (v - k omega) / R and its torque k times that
current. Once the rotor runs faster than the motor could drive it (k omega > v) the clutch frees:
no torque, no current, the motor never brakes the engine. Under PWM the battery delivers
duty x the motor's current.

Default motor: no-load at 70 %N from 24 V, 80 A stall from 24 V, about 400 W at 30-45 %N: enough
to carry the engine, with its first flame, past the speed where it makes more power than it
absorbs (about 30 %N for the nominal engine on its maps at start-up fuel flows, nearer 45 %N for
the weakest of a +-5 % health variation, whose lowest steady speed is about 46 %N).
"""

from __future__ import annotations

from numba import njit

from plant.jit import JIT

EMF_V_S_RAD = 24.0 / (0.7 * 112_500.0 * 3.141592653589793 / 30.0)  # k, referred to the rotor
RESISTANCE_OHM = 0.3


@njit(**JIT, inline="always")
def motor_current(v_motor: float, omega_rad_s: float, emf_v_s: float, r_ohm: float) -> float:
    """Winding current at mean terminal voltage v_motor; 0 once the clutch overruns."""
    i = (v_motor - emf_v_s * omega_rad_s) / r_ohm
    return i if i > 0.0 else 0.0


@njit(**JIT, inline="always")
def starter_torque(
    v_motor: float, omega_rad_s: float, emf_v_s: float, r_ohm: float, health: float
) -> float:
    """Torque on the rotor, N m (health 1 = new motor, 0 = dead)."""
    return health * emf_v_s * motor_current(v_motor, omega_rad_s, emf_v_s, r_ohm)
