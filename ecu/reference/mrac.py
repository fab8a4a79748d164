"""Float64 twin of ecu.mrac: eq. 5.4 and K_b (solved for u), eq. 5.15-5.16 (Euler), 5.18-5.19."""

from __future__ import annotations

from dataclasses import dataclass

from ecu.firmware_params import _tustin
from ecu.params import EcuParams, firmware_convention
from ecu.reference.estimator import FloatEstimator


@dataclass
class FloatMrac:
    params: EcuParams
    kx1: float = 0.0
    kx2: float = 0.0
    kr: float = 0.0
    kf1: float = 0.0
    kf2: float = 0.0
    kb: float = 0.0
    xm1: float = 0.0
    xm2: float = 0.0

    def __post_init__(self) -> None:
        self.params = p = firmware_convention(self.params)
        self.kx1, self.kx2 = p.init_kx
        self.kr = p.init_kr
        self.kf1, self.kf2 = p.init_kf
        if p.pump_scaling_on:
            self.kb = (p.trim_v - p.pump_dead_v) * (p.lambda_commissioned / p.init_lambda - 1.0)
        self.dt = 1.0 / p.rate_hz
        self.am21 = -(p.ref_wn**2)
        self.am22 = -2.0 * p.ref_zeta * p.ref_wn
        self.bm2 = p.ref_wn**2
        self.m, self.h = _tustin(self.am21, self.am22, self.dt)

    def control(self, dn: float, dv: float, r: float) -> float:
        num = self.kx1 * dn + self.kx2 * dv + self.kr * r
        den = max(1.0 - self.kf1 * dn - self.kf2 * dn * dn, self.params.u_den_min)
        return num / den + self.kb

    def gain_update(self, est: FloatEstimator) -> None:
        p, dt, lam = self.params, self.dt, est.lam
        self.kx1 -= p.gamma_x[0] * (est.ap21 - self.am21 + lam * self.kx1) * dt
        self.kx2 -= p.gamma_x[1] * (est.ap22 - self.am22 + lam * self.kx2) * dt
        self.kr -= p.gamma_r * (-self.bm2 + lam * self.kr) * dt
        self.kf1 -= p.gamma_f[0] * (est.th1 + lam * self.kf1) * dt
        self.kf2 -= p.gamma_f[1] * (est.th2 + lam * self.kf2) * dt
        self.kb -= p.gamma_b * (est.bias + lam * self.kb) * dt

    def reference_step(self, r: float) -> None:
        m, h = self.m, self.h
        xm1, xm2 = self.xm1, self.xm2
        self.xm1 = m[0] * xm1 + m[1] * xm2 + h[0] * self.bm2 * r
        self.xm2 = m[2] * xm1 + m[3] * xm2 + h[1] * self.bm2 * r
