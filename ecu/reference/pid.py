"""Float64 twin of ecu.pid (derivative on measurement, forward-Euler integrator, tracking)."""

from __future__ import annotations

from dataclasses import dataclass

from ecu.params import EcuParams


@dataclass
class FloatPid:
    params: EcuParams
    i: float = 0.0

    def control(self, e: float, dv: float) -> float:
        p = self.params
        self.i += p.pid_ki * e / p.rate_hz
        return p.pid_kp * e + self.i - p.pid_kd * dv

    def track(self, e: float, dv: float, u_applied: float) -> None:
        p = self.params
        self.i = u_applied - p.pid_kp * e + p.pid_kd * dv
