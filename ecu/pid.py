"""PID baseline of chapter 6 (P = 2, I = 1, D = 0.5 around 89.68 %N) with anti-windup.

u = Kp e + I - Kd dN'   (derivative on measurement, so a demand step gives no kick)
I[k+1] = I[k] + Ki e dt  (forward Euler, in a split accumulator so small steps add up)
Anti-windup by integrator tracking: after min/max selection and limits, I is recomputed so that
the PID output equals the voltage actually applied (back-calculation with infinite gain).
"""

from __future__ import annotations

from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import acc_q40, sat32
from ecu.state import PID_I, EcuState


def pid_control(s: EcuState, p: FirmwareParams, e: int, dv: int) -> int:
    """PID output u (Q7.24 V deviation) for speed error e and speed rate dv (Q7.24)."""
    acc_q40(s.theta_q24, s.theta_ext, PID_I, (e * p.pid_ki_dt_q28) >> 12)
    i_q24 = s.theta_q24[PID_I]
    return sat32(((p.pid_kp_q24 * e) >> 24) + i_q24 - ((p.pid_kd_q24 * dv) >> 24))


def pid_track(s: EcuState, p: FirmwareParams, e: int, dv: int, u_applied: int) -> None:
    """Integrator tracking: I = u_applied - Kp e + Kd dN', so the loop resumes bumplessly."""
    s.theta_q24[PID_I] = sat32(u_applied - ((p.pid_kp_q24 * e) >> 24) + ((p.pid_kd_q24 * dv) >> 24))
    s.theta_ext[PID_I] = 0
