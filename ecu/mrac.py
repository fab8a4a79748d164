"""Indirect MRAC: control law (eq. 5.4), gain update laws (eq. 5.15-5.16), reference model
(eq. 5.18-5.19).

B_p = [0, 1]^T, so B_p^T picks row 2 of the extra errors (eq. 5.15); per step (forward Euler):

    eps_x[i] = A_p-hat[2][i] - A_m[2][i] + Lambda-hat K_x[i]     K_x[i] -= Gamma_x[i] eps_x[i] dt
    eps_r    = -B_m[2] + Lambda-hat K_r                          K_r    -= Gamma_r eps_r dt
    eps_f[i] = Theta_f-hat[2][i] + Lambda-hat K_f[i]             K_f[i] -= Gamma_f[i] eps_f[i] dt
    eps_b    = d-hat + Lambda-hat K_b                            K_b    -= Gamma_b eps_b dt

d-hat is the estimator's fuel-path bias d0 = (Lambda-hat - Lambda_c) V0 (pump_scaling_on; else
0, and K_b stays 0). The plant's bias g(dN) d0 has the shape g(dN) = 1 - K_f1 dN - K_f2 dN^2 of
its input effectiveness Lambda g(dN), so a constant K_b added to u cancels it: 0 = Lambda K_b
+ d0, the matching condition of eq. 5.14 for one more term.

Eq. 5.4, u = K_x x + K_r r + K_f f(x, u) with f = [dN u, dN^2 u], is implicit in u; it is solved
exactly: u = (K_x x + K_r r) / (1 - K_f1 dN - K_f2 dN^2), the divisor kept above a floor; then
the bias gain K_b is added.
The reference model x_m' = A_m x_m + B_m r is discretised by the trapezoidal rule with r held.
"""

from __future__ import annotations

from ecu.estimator import pump_bias_q16
from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import acc_q40, add_sat, div_trunc, sat32
from ecu.state import AP21, AP22, KB, KF1, KF2, KR, KX1, KX2, LAM, TH1, TH2, EcuState


def mrac_control(s: EcuState, p: FirmwareParams, dn: int, dv: int, r: int) -> int:
    """Eq. 5.4 solved for u (Q7.24 V deviation); dn, dv: x (Q7.24), r: speed command deviation."""
    th = s.theta_q24
    num = sat32(((th[KX1] * dn) >> 24) + ((th[KX2] * dv) >> 24) + ((th[KR] * r) >> 24))
    kf2_dn = (th[KF2] * dn) >> 24
    den = sat32((1 << 24) - ((th[KF1] * dn) >> 24) - ((kf2_dn * dn) >> 24))
    if den < p.u_den_min_q24:
        den = p.u_den_min_q24
    return add_sat(div_trunc(num << 24, den), th[KB])


def command_lag(s: EcuState, p: FirmwareParams, u: int) -> int:
    """The MRAC's command through the first-order lag of mrac_cmd_lag_s (backward Euler,
    c = dt / (tau + dt) in Q24; c = 1 passes u): lag and engine are then the fast model. While
    a limit owns the pump the lag tracks the applied voltage (the firmware sets it), so the
    speed loop takes over from there."""
    lag = s.u_lag_q24
    lag = s.u_lag_q24 = sat32(lag + ((p.mrac_lag_c_q24 * (u - lag)) >> 24))
    return lag


def mrac_gain_update(s: EcuState, p: FirmwareParams) -> None:
    """Eq. 5.15-5.16 for K_x, K_r, K_f and K_b, driven by the current estimates."""
    th = s.theta_q24
    ext = s.theta_ext
    lam = th[LAM]
    eps = sat32(th[AP21] - p.ref_am21_q24 + ((lam * th[KX1]) >> 24))
    acc_q40(th, ext, KX1, (-eps * p.g_x1_q28) >> 12)
    eps = sat32(th[AP22] - p.ref_am22_q24 + ((lam * th[KX2]) >> 24))
    acc_q40(th, ext, KX2, (-eps * p.g_x2_q28) >> 12)
    eps = sat32(-p.ref_bm2_q24 + ((lam * th[KR]) >> 24))
    acc_q40(th, ext, KR, (-eps * p.g_r_q28) >> 12)
    eps = sat32(th[TH1] + ((lam * th[KF1]) >> 24))
    acc_q40(th, ext, KF1, (-eps * p.g_f1_q28) >> 12)
    eps = sat32(th[TH2] + ((lam * th[KF2]) >> 24))
    acc_q40(th, ext, KF2, (-eps * p.g_f2_q28) >> 12)
    eps = sat32((pump_bias_q16(th, p) << 8) + ((lam * th[KB]) >> 24))
    acc_q40(th, ext, KB, (-eps * p.g_b_q28) >> 12)


def reference_model_step(s: EcuState, p: FirmwareParams, r: int) -> None:
    """Eq. 5.18-5.19, x_m[k+1] = M x_m[k] + h r[k] (trapezoidal, r held)."""
    xm1 = s.xm1_q24
    xm2 = s.xm2_q24
    s.xm1_q24 = sat32(
        ((p.refm11_q24 * xm1) >> 24) + ((p.refm12_q24 * xm2) >> 24) + ((p.refh1_q24 * r) >> 24)
    )
    s.xm2_q24 = sat32(
        ((p.refm21_q24 * xm1) >> 24) + ((p.refm22_q24 * xm2) >> 24) + ((p.refh2_q24 * r) >> 24)
    )
