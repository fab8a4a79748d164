"""Online estimator: identification model (eq. 4.7) and parameter update laws (eq. 4.31).

x = [dN, dN'] (deviations from trim, %N and %N/s), u = dV (V), f(x, u) = [dN dV, dN^2 dV].
Row 1 of A_p and Theta_f is kinematic (dN/dt = dN') and known, so only row 2 is adapted; with a
diagonal P the laws of eq. 4.31 for row 2 read, per step of length dt (forward Euler):

    A_p-hat[2][i]  -= Gamma_A[i] P22 x_i     e dt
    Lambda-hat     -= Gamma_L    P22 u       e dt
    Theta_f-hat[2][i] -= Gamma_T[i] P22 f_i  e dt

with e = e2 for the document's P (see p12 below).

The ECU measures N only: the speed rate is a central difference over +-m samples, so the
estimator runs m + 1 ticks late on the interval [j, j+1], with x at its ends and the input u[j]
held over it. The identification model is discretised by the trapezoidal rule (Tustin) with
x, f at the interval's mid point (plain Euler would bias Lambda-hat by about dt/2 A22), and the
update laws are semi-implicit Euler: mid-interval regressors times the error at the interval's
end, computed with the parameters of the previous step. Explicit Euler (error at the start)
diverges with the document's sec. 4.2 gains at 100 Hz (Gamma_Theta2 f2^2 dt is about 50);
the semi-implicit form is stable there, as the continuous laws are.

With p12 > 0 the laws are driven by (P e)_2 / p22 = e2 + (p12 / p22) e1 (a full Lyapunov P of
A_m; the document's diagonal P sees parameter errors only through e2, blind in steady state).

With pump_scaling_on the pump's effectiveness scales the whole fuel path. The commissioned
fuel term is Lambda_c g(dN) dV with g(dN) = 1 + r1 dN + r2 dN^2, r = Theta_c / Lambda_c; a pump
of another effectiveness delivers what the commissioned one would at Lambda-hat / Lambda_c
times its voltage above the dead voltage V_d (V = V0 + u), so the fuel terms of eq. 4.7 become
g(dN) (Lambda-hat (u + V0 - V_d) - Lambda_c (V0 - V_d)): Lambda-hat u + Theta_f-hat f with
Theta_f-hat = Lambda-hat r, plus the bias g(dN) d0, d0 = (Lambda-hat - Lambda_c) (V0 - V_d),
that moves the trim voltage with the pump. One parameter for what a worn or failed pump
changes, with the regressor g(dN) (u + V0 - V_d), rich in steady state too; Theta_f-hat is not
adapted on its own then.

Robustness (each switchable): Lambda-hat floor (projection), dead zone on the driving error
sized from the rate noise, and no adaptation when the caller says so (limiter owns the command,
V saturates).
"""

from __future__ import annotations

from array import array

from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import acc_q40, mul_q, mul_q24, mul_q24_round, mul_q_round, sat32, sub_sat
from ecu.state import AP21, AP22, LAM, TH1, TH2, EcuState

R32 = 1 << 31  # adds half an LSB before a >> 32: round to nearest (ties up), not down
R24 = 1 << 23


def _increment_q40(phi_e_q16: int, gain_q28: int) -> int:
    """Eq. 4.31's step -(Gamma P dt) phi e in Q7.40, rounded to nearest: the adaptation
    integrates it for as long as the engine runs, so a truncation's half-LSB bias per tick would
    drift the estimates along the directions the input excites least."""
    return (-phi_e_q16 * gain_q28 + 8) >> 4


def pump_bias_q16(th: array, p: FirmwareParams) -> int:
    """d0 = (Lambda-hat - Lambda_c) (V0 - V_d) in %N/s^2 (Q15.16); 0 without pump scaling. The fuel
    path's bias is g(dN) d0, with g(dN) = 1 + r1 dN + r2 dN^2 its commissioned shape."""
    if not p.pump_scaling_on:
        return 0
    return sat32(((th[LAM] * p.pump_v0_q24) >> 32) - p.lam_comm_v0_q16)


def fuel_shape_q24(p: FirmwareParams, n_q24: int, nn_q16: int) -> int:
    """g(dN) = 1 + r1 dN + r2 dN^2 (Q7.24) from dN (Q7.24) and dN^2 (Q15.16)."""
    return sat32(
        (1 << 24) + ((p.th_per_lam1_q28 * n_q24) >> 28) + ((p.th_per_lam2_q28 * nn_q16) >> 20)
    )


def estimator_step(
    s: EcuState, p: FirmwareParams, n0: int, v0: int, n1: int, v1: int, u: int, adapt: int
) -> None:
    """One interval of eq. 4.7 / 4.31. n, v: dN, dN' at the interval ends (Q7.24); u: dV (Q7.24)."""
    th = s.theta_q24
    n_mid = (n0 + n1) >> 1
    v_mid = (v0 + v1) >> 1
    f1 = mul_q24(u, n_mid)  # f1 = dN dV, mid interval (Q7.24)
    nn_q16 = ((n0 * n0) >> 33) + ((n1 * n1) >> 33)  # (dN0^2 + dN1^2) / 2 (Q15.16)
    f2_q16 = mul_q24(u, nn_q16)  # f2 = dN^2 dV, mid interval (Q15.16)
    g = fuel_shape_q24(p, n_mid, nn_q16)
    # eq. 4.7 row 2 forcing: (A_p-hat - A_m) x + B_p Lambda-hat u + Theta_f-hat f, in %N/s^2;
    # with a fast A_m it exceeds the Q7.24 range in large transients, so it is Q15.16
    c2_q16 = sat32(
        (((th[AP21] - p.am21_q24) * n_mid) >> 32)
        + (((th[AP22] - p.am22_q24) * v_mid) >> 32)
        + ((th[LAM] * u) >> 32)
        + ((th[TH1] * f1) >> 32)
        + ((th[TH2] * f2_q16) >> 24)
        + ((pump_bias_q16(th, p) * g) >> 24)
    )
    # x-hat[k+1] = M x-hat[k] + h c2 (Tustin of x-hat' = A_m x-hat + [0, c2])
    xh1 = s.xh1_q24
    xh2 = s.xh2_q24
    s.xh1_q24 = sat32(
        ((p.idm11_q24 * xh1) >> 24) + ((p.idm12_q24 * xh2) >> 24) + ((p.idh1_q24 * c2_q16) >> 16)
    )
    s.xh2_q24 = sat32(
        ((p.idm21_q24 * xh1) >> 24) + ((p.idm22_q24 * xh2) >> 24) + ((p.idh2_q24 * c2_q16) >> 16)
    )
    e2 = sub_sat(s.xh2_q24, v1)  # e_I row 2 (eq. 4.8) at the end of the interval
    s.e2_q24 = e2
    if not adapt:
        return
    # (P e)_2 / p22: the error that drives eq. 4.31
    e = sat32(e2 + ((p.p12_ratio_q24 * sub_sat(s.xh1_q24, n1)) >> 24))
    if p.dead_zone_on and -p.dead_zone_q24 < e < p.dead_zone_q24:
        return
    # eq. 4.31: increments -(Gamma P dt) phi e in Q7.40: phi e in Q15.16 (it exceeds the Q7.24
    # range in transients) times Gamma P dt in Q3.28, >> 4
    ext = s.theta_ext
    acc_q40(th, ext, AP21, _increment_q40(mul_q_round(n_mid, e, 32), p.g_a1_q28))
    acc_q40(th, ext, AP22, _increment_q40(mul_q_round(v_mid, e, 32), p.g_a2_q28))
    if p.pump_scaling_on:
        phi = sat32((g * (u + p.pump_v0_q24)) >> 24)  # Lambda-hat's regressor g(dN) (u + V0 - V_d)
        acc_q40(th, ext, LAM, _increment_q40(mul_q_round(phi, e, 32), p.g_lam_q28))
    else:
        acc_q40(th, ext, LAM, _increment_q40(mul_q_round(u, e, 32), p.g_lam_q28))
        acc_q40(th, ext, TH1, _increment_q40(mul_q_round(f1, e, 32), p.g_th1_q28))
        acc_q40(th, ext, TH2, _increment_q40(mul_q24_round(f2_q16, e), p.g_th2_q28))
    if p.lambda_floor_on and th[LAM] < p.lambda_floor_q24:  # projection onto Lambda >= floor
        th[LAM] = p.lambda_floor_q24
        ext[LAM] = 0
    if p.pump_scaling_on:  # Theta_f-hat = Lambda-hat r
        th[TH1] = mul_q(th[LAM], p.th_per_lam1_q28, 28)
        th[TH2] = mul_q(th[LAM], p.th_per_lam2_q28, 28)
        ext[TH1] = 0
        ext[TH2] = 0
