"""The ECU's two engine sensors: a shaft-speed pickup and an EGT thermocouple.

Speed pickup (inductive, one pulse train per blade pass): the reading is quantised to the
counter's resolution and carries white noise; with a dropout probability a reading is lost and
reads 0 rpm. Faults: dropout (reads 0), stuck (holds its last reading), noise burst (extra noise).
Thermocouple: first-order lag of the probe plus white noise; an open circuit reads the ADC's
upscale burnout value, as thermocouple amplifiers do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant.noise import NoiseSource


def _check(name: str, value: float, minimum: float = 0.0) -> float:
    value = float(value)
    if not math.isfinite(value) or value < minimum:
        raise ValueError(f"{name} must be a finite number >= {minimum}, got {value!r}")
    return value


@dataclass(frozen=True)
class SpeedPickupConfig:
    resolution_rpm: float = 10.0
    noise_rpm: float = 20.0  # 1 sigma
    dropout_probability: float = 0.0  # per reading
    bias_rpm: float = 0.0  # calibration offset of the reading

    def __post_init__(self) -> None:
        _check("resolution_rpm", self.resolution_rpm)
        _check("noise_rpm", self.noise_rpm)
        _check("bias_rpm", self.bias_rpm, -math.inf)
        if not 0.0 <= self.dropout_probability <= 1.0:
            raise ValueError(
                f"dropout_probability must be in [0, 1], got {self.dropout_probability!r}"
            )


@dataclass(frozen=True)
class ThermocoupleConfig:
    time_constant_s: float = 0.5
    noise_k: float = 1.0  # 1 sigma
    open_circuit_k: float = 1638.3  # upscale burnout: full scale of the EGT signal
    bias_k: float = 0.0  # calibration offset of the reading

    def __post_init__(self) -> None:
        _check("time_constant_s", self.time_constant_s)
        _check("noise_k", self.noise_k)
        _check("bias_k", self.bias_k, -math.inf)
        _check("open_circuit_k", self.open_circuit_k)


class SpeedPickup:
    """Speed reading in rpm from the true speed, one reading per ECU period."""

    def __init__(self, config: SpeedPickupConfig, noise: NoiseSource) -> None:
        self.config = config
        self._noise = noise
        self.dropout = False
        self.stuck = False
        self.burst_noise_rpm = 0.0
        self._last = 0.0

    def read(self, n_rpm: float) -> float:
        c = self.config
        # draw every sample on every reading so that faults do not shift the noise sequence
        z, u = self._noise.normal(), self._noise.uniform()
        sigma = math.hypot(c.noise_rpm, self.burst_noise_rpm)
        value = max(n_rpm + c.bias_rpm + sigma * z, 0.0)
        if c.resolution_rpm > 0.0:
            value = round(value / c.resolution_rpm) * c.resolution_rpm
        if self.dropout or u < c.dropout_probability:
            value = 0.0
        if self.stuck:
            value = self._last
        self._last = value
        return value


class Thermocouple:
    """EGT reading in K: first-order lag of the probe, noise, open-circuit fault."""

    def __init__(self, config: ThermocoupleConfig, noise: NoiseSource, t_initial_k: float) -> None:
        self.config = config
        self._noise = noise
        self.open_circuit = False
        self.probe_k = t_initial_k

    def read(self, egt_k: float, dt_s: float) -> float:
        c = self.config
        z = self._noise.normal()
        if c.time_constant_s > 0.0:
            self.probe_k += (egt_k - self.probe_k) * (1.0 - math.exp(-dt_s / c.time_constant_s))
        else:
            self.probe_k = egt_k
        if self.open_circuit:
            return c.open_circuit_k
        return self.probe_k + c.bias_k + c.noise_k * z
