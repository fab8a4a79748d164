"""Float64 twin of ecu.estimator: eq. 4.7 (trapezoidal, mid-interval x) and eq. 4.31 (Euler)."""

from __future__ import annotations

from dataclasses import dataclass

from ecu.firmware_params import _tustin
from ecu.params import EcuParams, firmware_convention


@dataclass
class FloatEstimator:
    params: EcuParams
    ap21: float = 0.0
    ap22: float = 0.0
    lam: float = 0.0
    th1: float = 0.0
    th2: float = 0.0
    xh1: float = 0.0
    xh2: float = 0.0
    e2: float = 0.0

    def __post_init__(self) -> None:
        self.params = p = firmware_convention(self.params)
        self.ap21, self.ap22 = p.init_ap_row2
        self.lam = p.init_lambda
        self.th1, self.th2 = p.init_theta_row2
        self.dt = 1.0 / p.rate_hz
        self.m, self.h = _tustin(p.am_row2[0], p.am_row2[1], self.dt)
        # pump scaling: Theta_f-hat = Lambda-hat r with the commissioned ratios
        self.r = tuple(t / p.lambda_commissioned for t in p.init_theta_row2)
        if p.pump_scaling_on:
            self.th1, self.th2 = (r * self.lam for r in self.r)

    @property
    def bias(self) -> float:
        """d0 = (Lambda-hat - Lambda_c) (V0 - V_d), %N/s^2 (pump scaling); the fuel path's bias
        is g(dN) d0."""
        p = self.params
        if not p.pump_scaling_on:
            return 0.0
        return (self.lam - p.lambda_commissioned) * (p.trim_v - p.pump_dead_v)

    def shape(self, n: float, nn: float) -> float:
        """g(dN) = 1 + r1 dN + r2 dN^2, with dN^2 given."""
        return 1.0 + self.r[0] * n + self.r[1] * nn

    def step(
        self,
        n0: float,
        v0: float,
        n1: float,
        v1: float,
        u: float,
        adapt: bool,
        dead_zone: float = 0.0,
    ) -> None:
        p = self.params
        n_mid = 0.5 * (n0 + n1)
        v_mid = 0.5 * (v0 + v1)
        f1 = u * n_mid
        nn = 0.5 * (n0 * n0 + n1 * n1)
        f2 = u * nn
        g = self.shape(n_mid, nn)
        c2 = (
            (self.ap21 - p.am_row2[0]) * n_mid
            + (self.ap22 - p.am_row2[1]) * v_mid
            + self.lam * u
            + self.th1 * f1
            + self.th2 * f2
            + g * self.bias
        )
        m, h = self.m, self.h
        xh1, xh2 = self.xh1, self.xh2
        self.xh1 = m[0] * xh1 + m[1] * xh2 + h[0] * c2
        self.xh2 = m[2] * xh1 + m[3] * xh2 + h[1] * c2
        e2 = self.xh2 - v1
        self.e2 = e2
        e = e2 + p.p12 / p.p22 * (self.xh1 - n1)  # (P e)_2 / p22
        if not adapt or abs(e) < dead_zone:
            return
        k = p.p22 * self.dt * e
        self.ap21 -= p.gamma_a[0] * k * n_mid
        self.ap22 -= p.gamma_a[1] * k * v_mid
        if p.pump_scaling_on:
            self.lam -= p.gamma_lambda * k * g * (u + p.trim_v - p.pump_dead_v)
        else:
            self.lam -= p.gamma_lambda * k * u
            self.th1 -= p.gamma_theta[0] * k * f1
            self.th2 -= p.gamma_theta[1] * k * f2
        if p.lambda_floor_on and self.lam < p.lambda_floor:
            self.lam = p.lambda_floor
        if p.pump_scaling_on:
            self.th1, self.th2 = (r * self.lam for r in self.r)
