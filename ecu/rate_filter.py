"""The speed rate for the control laws and limit loops: a tracking filter on the measured speed
(a steady-state Kalman filter of a constant-acceleration model) that is told the pump's input,
in deviations from trim.

    innovation  e    = dN_meas - dN-hat
    dN-hat[k+1]  = dN-hat + dt v-hat                                       + k1 e
    v-hat[k+1]   = v-hat  + dt (a-hat + (Lambda + Th1 dN + Th2 dN^2) dV)  + k2 e
    a-hat[k+1]   = a-hat                                                    + k3 e

The input term is the fast model's (eq. 3.5) with the estimator's current Lambda-hat and
Theta_f-hat and the voltage applied over the last tick: a pump step moves v-hat at once, so the
filter adds no lag inside the speed loop. Everything else the engine does (A_p dN, the fuel
path's bias, whatever the model misses) is a-hat, an acceleration the filter learns: it needs
no A_p, holds far from trim and on an engine unlike the commissioned one, and a constant
acceleration leaves no steady-state error on v-hat. With k1 = 3c, k2 = 3c^2/dt, k3 = c^3/dt^2
and c = 1 - exp(-w dt), its error dynamics have a triple pole at z = exp(-w dt) (w =
rate_filter_bw): det(zI - A + K C) = (z - 1 + c)^3.
"""

from __future__ import annotations

from ecu.fast_model import input_accel_q16
from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import sat32
from ecu.state import EcuState


def rate_filter_start(s: EcuState, dn: int) -> None:
    """Start on a speed sample: at rest there."""
    s.rf_n_q24 = dn
    s.rf_v_q24 = 0
    s.rf_a_q16 = 0


def rate_filter_step(s: EcuState, p: FirmwareParams, dn: int, u: int, valid: int) -> None:
    """Advance one tick with the speed deviation dn and the voltage deviation u applied over
    the last tick (Q7.24); without a valid sample, predict."""
    n = s.rf_n_q24
    v = s.rf_v_q24
    a = s.rf_a_q16
    e = sat32(dn - n) if valid else 0
    acc_q16 = sat32(a + input_accel_q16(s.theta_q24, n, u))
    s.rf_n_q24 = sat32(n + ((p.dt_q24 * v) >> 24) + ((p.rf_k1_q24 * e) >> 24))
    s.rf_v_q24 = sat32(v + ((p.dt_q24 * acc_q16) >> 16) + ((p.rf_k2_q24 * e) >> 24))
    s.rf_a_q16 = sat32(a + ((p.rf_k3_q24 * e) >> 32))
