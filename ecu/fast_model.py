"""Fast engine model (eq. 3.5) run as an observer, in deviations from the trim point.

    dN'  = v                                                     + L1 (N_meas - N-hat)
    v'   = A21 dN + A22 v + Lambda dV + Th1 dN dV + Th2 dN^2 dV  + L2 (N_meas - N-hat)
           + g(dN) (Lambda - Lambda_c) V0   (the fuel-path bias, with pump_scaling_on)

with the estimator's current parameters (eq. 3.5 in the form of eq. 4.6), forward Euler.
While the speed sensor is valid the correction keeps the model on the measurement; when it
fails the correction is switched off and the model runs open loop as the analytical redundancy
that replaces the sensor.
"""

from __future__ import annotations

from array import array

from ecu.estimator import fuel_shape_q24, pump_bias_q16
from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import sat32
from ecu.state import AP21, AP22, LAM, TH1, TH2, EcuState


def input_accel_q16(th: array, n: int, u: int) -> int:
    """The input's acceleration (Lambda + Th1 dN + Th2 dN^2) dV in %N/s^2 (Q15.16, not
    saturated) for dN and dV in Q7.24."""
    th2_n = (th[TH2] * n) >> 24
    return (
        ((th[LAM] * u) >> 32)
        + ((((th[TH1] * n) >> 24) * u) >> 32)
        + ((((th2_n * n) >> 24) * u) >> 32)
    )


def observer_step(s: EcuState, p: FirmwareParams, u: int, dn_meas: int, valid: int) -> None:
    """Advance the observer one tick with input u (Q7.24 V deviation)."""
    th = s.theta_q24
    n = s.obs_n_q24
    v = s.obs_v_q24
    innov = sat32(dn_meas - n) if valid else 0
    # acceleration in %N/s^2 (Q15.16: it exceeds the Q7.24 range far from trim)
    acc_q16 = sat32(
        ((th[AP21] * n) >> 32)
        + ((th[AP22] * v) >> 32)
        + input_accel_q16(th, n, u)
        + ((pump_bias_q16(th, p) * fuel_shape_q24(p, n, (n * n) >> 32)) >> 24)
    )
    s.obs_n_q24 = sat32(n + ((p.dt_q24 * v) >> 24) + ((p.obs_l1_dt_q24 * innov) >> 24))
    s.obs_v_q24 = sat32(v + ((p.dt_q24 * acc_q16) >> 16) + ((p.obs_l2_dt_q24 * innov) >> 24))
