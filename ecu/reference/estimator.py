"""Float64 twin of ecu.estimator: eq. 4.7 (trapezoidal, mid-interval x) and eq. 4.31 (Euler)."""

from __future__ import annotations

from dataclasses import dataclass

from ecu.params import EcuParams, _tustin


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
        p = self.params
        self.ap21, self.ap22 = p.init_ap_row2
        self.lam = p.init_lambda
        self.th1, self.th2 = p.init_theta_row2
        self.dt = 1.0 / p.rate_hz
        self.m, self.h = _tustin(p.am_row2[0], p.am_row2[1], self.dt)

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
        f2 = u * 0.5 * (n0 * n0 + n1 * n1)
        c2 = (
            (self.ap21 - p.am_row2[0]) * n_mid
            + (self.ap22 - p.am_row2[1]) * v_mid
            + self.lam * u
            + self.th1 * f1
            + self.th2 * f2
        )
        m, h = self.m, self.h
        xh1, xh2 = self.xh1, self.xh2
        self.xh1 = m[0] * xh1 + m[1] * xh2 + h[0] * c2
        self.xh2 = m[2] * xh1 + m[3] * xh2 + h[1] * c2
        e2 = self.xh2 - v1
        self.e2 = e2
        if not adapt or abs(e2) < dead_zone:
            return
        k = p.p22 * self.dt * e2
        self.ap21 -= p.gamma_a[0] * k * n_mid
        self.ap22 -= p.gamma_a[1] * k * v_mid
        self.lam -= p.gamma_lambda * k * u
        self.th1 -= p.gamma_theta[0] * k * f1
        self.th2 -= p.gamma_theta[1] * k * f2
        if p.lambda_floor_on and self.lam < p.lambda_floor:
            self.lam = p.lambda_floor
