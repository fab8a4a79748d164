"""Gain-scheduled PI baseline (gains from ecu.pi_design) with the PID's anti-windup.

u = Kp(N) e + I,   I[k+1] = I[k] + Ki(N) e dt   (forward Euler, split accumulator)

Kp and Ki are interpolated linearly in the measured speed N between the scheduling speeds
(pi_n0 + k pi_step, k = 0..PI_POINTS-1) and held beyond the ends. I is in volts, so a change of
gains moves no voltage. Anti-windup by integrator tracking: after min/max selection and limits
I = u_applied - Kp e, so the loop resumes bumplessly when a limit loop lets go.
"""

from __future__ import annotations

from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import acc_q40, sat32
from ecu.state import PID_I, EcuState
from ecu.tables import interp_uniform


def scheduled(p: FirmwareParams, table: tuple[int, ...], n_q24: int) -> int:
    """table at speed n_q24 (Q7.24 %N), linear between the scheduling speeds."""
    return interp_uniform(table, p.pi_n0_q24, p.pi_step_q24, n_q24)


def pi_control(s: EcuState, p: FirmwareParams, e: int, n_q24: int) -> int:
    """PI output u (Q7.24 V deviation) for speed error e (Q7.24 %N) at speed n_q24."""
    acc_q40(s.theta_q24, s.theta_ext, PID_I, (e * scheduled(p, p.pi_ki_dt_q28, n_q24)) >> 12)
    return sat32(((scheduled(p, p.pi_kp_q24, n_q24) * e) >> 24) + s.theta_q24[PID_I])


def pi_track(s: EcuState, p: FirmwareParams, e: int, n_q24: int, u_applied: int) -> None:
    """Integrator tracking: I = u_applied - Kp e."""
    s.theta_q24[PID_I] = sat32(u_applied - ((scheduled(p, p.pi_kp_q24, n_q24) * e) >> 24))
    s.theta_ext[PID_I] = 0
