"""Float64 twin of ecu.rate_filter: the tracking filter on a constant-acceleration model, told
the pump's input."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ecu.params import EcuParams


@dataclass
class FloatRateFilter:
    """dN-hat (%N), v-hat (%N/s), a-hat (%N/s^2), triple pole at z = exp(-rate_filter_bw dt)."""

    params: EcuParams
    n: float = 0.0
    v: float = 0.0
    a: float = 0.0

    def __post_init__(self) -> None:
        self.dt = dt = 1.0 / self.params.rate_hz
        c = 1.0 - math.exp(-self.params.rate_filter_bw * dt)
        self.k = (3.0 * c, 3.0 * c * c / dt, c**3 / (dt * dt))

    def start(self, dn: float) -> None:
        self.n, self.v, self.a = dn, 0.0, 0.0

    def step(
        self, dn: float, u: float, gain: tuple[float, float, float], valid: bool = True
    ) -> None:
        """dn: speed deviation (%N); u: voltage deviation over the last tick (V); gain: Lambda,
        Theta_f row 2 (the input's acceleration (Lambda + Th1 dN + Th2 dN^2) u)."""
        e = dn - self.n if valid else 0.0
        k1, k2, k3 = self.k
        n = self.n
        acc = self.a + (gain[0] + gain[1] * n + gain[2] * n * n) * u
        self.n += self.dt * self.v + k1 * e
        self.v += self.dt * acc + k2 * e
        self.a += k3 * e
