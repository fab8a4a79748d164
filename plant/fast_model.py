"""The fast engine model of eq. 3.24 as a plant: shaft dynamics plus pump, voltage in, speed out.

dN'' = theta0 dN + theta1 dN' + theta2 dV + theta3 dN dV + theta4 dN^2 dV      (3.8, 3.24)

in deviations from a trim point (N in %N_max, V in volts). The document uses it to verify the
online estimator (sec. 4.2) and the indirect MRAC (sec. 5.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# eq. 3.23: [-wn^2, -2 zeta wn, a0 wn^2, a1 wn^2, a2 wn^2]
THETA_EQ_3_23 = (-1.8054, -2.3360, 4.8220, -0.1835, -0.0001)
TRIM_N_PCT = 89.68


def fast_model_derivative(
    dn_pct: float, dn_dot: float, dv_volt: float, theta: tuple[float, ...]
) -> tuple[float, float]:
    """d/dt [dN, dN'] of eq. 3.5 for the deviations dN (%), dN' (%/s) and dV (V)."""
    t0, t1, t2, t3, t4 = theta
    dn_ddot = t0 * dn_pct + t1 * dn_dot + (t2 + t3 * dn_pct + t4 * dn_pct * dn_pct) * dv_volt
    return dn_dot, dn_ddot


def rate_per_volt(omega: float, theta: tuple[float, ...] = THETA_EQ_3_23) -> float:
    """|dN' / dV| at trim at omega rad/s, %N/s per V: the pump in the shaft's acceleration,
    s theta2 / (s^2 - theta1 s - theta0), which rolls off above the model's poles."""
    s = 1j * omega
    return float(abs(s * theta[2] / (s * s - theta[1] * s - theta[0])))


@dataclass
class FastEngine:
    """Eq. 3.24 integrated with RK4 (input held over a step), in deviations from trim.

    ``lambda_scale`` scales the pump effectiveness (theta2..theta4, the input terms), which is how
    the document's pump failure (effectiveness halved) acts on this model.
    """

    theta: tuple[float, ...] = THETA_EQ_3_23
    trim_n_pct: float = TRIM_N_PCT
    dn_pct: float = 0.0
    dn_dot: float = 0.0
    lambda_scale: float = 1.0

    @property
    def n_pct(self) -> float:
        return self.trim_n_pct + self.dn_pct

    def step(self, dv_volt: float, dt_s: float) -> None:
        if not np.isfinite(dv_volt) or not np.isfinite(dt_s) or dt_s <= 0.0:
            raise ValueError(f"FastEngine.step: bad input dv={dv_volt!r} dt={dt_s!r}")
        t = self.theta
        theta = (
            t[0],
            t[1],
            t[2] * self.lambda_scale,
            t[3] * self.lambda_scale,
            t[4] * self.lambda_scale,
        )
        x1, x2 = self.dn_pct, self.dn_dot
        k1 = fast_model_derivative(x1, x2, dv_volt, theta)
        k2 = fast_model_derivative(x1 + 0.5 * dt_s * k1[0], x2 + 0.5 * dt_s * k1[1], dv_volt, theta)
        k3 = fast_model_derivative(x1 + 0.5 * dt_s * k2[0], x2 + 0.5 * dt_s * k2[1], dv_volt, theta)
        k4 = fast_model_derivative(x1 + dt_s * k3[0], x2 + dt_s * k3[1], dv_volt, theta)
        self.dn_pct = x1 + dt_s / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        self.dn_dot = x2 + dt_s / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
