"""Float64 twin of ecu.pi: the scheduled PI with its forward-Euler integrator and tracking."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ecu.firmware_params import pi_schedule
from ecu.params import EcuParams


@dataclass
class FloatPi:
    params: EcuParams
    i: float = 0.0
    speeds: np.ndarray = field(init=False)
    kp: np.ndarray = field(init=False)
    ki: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        points = pi_schedule(self.params)
        self.speeds = np.array([pt.n_pct for pt in points])
        self.kp = np.array([pt.kp for pt in points])
        self.ki = np.array([pt.ki for pt in points])

    def gains(self, n_pct: float) -> tuple[float, float]:
        """(Kp, Ki) at speed n_pct, linear between the scheduling speeds, held beyond."""
        return (
            float(np.interp(n_pct, self.speeds, self.kp)),
            float(np.interp(n_pct, self.speeds, self.ki)),
        )

    def control(self, e: float, n_pct: float) -> float:
        kp, ki = self.gains(n_pct)
        self.i += ki * e / self.params.rate_hz
        return kp * e + self.i

    def track(self, e: float, n_pct: float, u_applied: float) -> None:
        self.i = u_applied - self.gains(n_pct)[0] * e
