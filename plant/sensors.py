"""The ECU's two engine sensors: a shaft-speed pickup and an EGT thermocouple.

Speed pickup (inductive, one pulse train per blade pass): the reading is quantised to the
counter's resolution and carries white noise; with a dropout probability a reading is lost and
reads 0 rpm. Faults: dropout (reads 0), stuck (holds its last reading), noise burst (extra noise).
Thermocouple: first-order lag of the probe plus white noise; an open circuit reads the ADC's
upscale burnout value, as thermocouple amplifiers do.

A reading is compiled (``speed_reading``, ``thermocouple_reading``, part of the plant's compiled
period): a sensor's settings, state and fault switches are slots of the plant's state array
(plant/periphery.py) from a base index, which ``SpeedPickup`` and ``Thermocouple`` read and set.
The compiled readings do the float arithmetic of the Python they replaced, operation for
operation (plant.jit.EXACT: no fast-math), so readings are the same bits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from plant.jit import EXACT


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


# slots of the speed pickup in the state array, from its base
SP_RESOLUTION, SP_BIAS, SP_DROPOUT_P, SP_SIGMA, SP_DROPOUT, SP_STUCK, SP_LAST = range(7)
SP_SLOTS = 7
# slots of the thermocouple
TC_LAG, TC_ALPHA, TC_PROBE, TC_BIAS, TC_NOISE, TC_OPEN_K, TC_OPEN = range(7)
TC_SLOTS = 7


@njit(**EXACT, inline="always")
def speed_reading(s: np.ndarray, b: int, n_rpm: float, z: float, u: float) -> float:
    """Speed reading (rpm) from the true speed, one standard normal z and one uniform u (both
    drawn on every reading, so that faults do not shift the noise sequence)."""
    value = n_rpm + s[b + SP_BIAS] + s[b + SP_SIGMA] * z
    if 0.0 > value:  # max(value, 0.0)
        value = 0.0
    resolution = s[b + SP_RESOLUTION]
    if resolution > 0.0:
        value = int(np.rint(value / resolution)) * resolution  # round half to even, as round()
    if s[b + SP_DROPOUT] != 0.0 or u < s[b + SP_DROPOUT_P]:
        value = 0.0
    if s[b + SP_STUCK] != 0.0:
        value = s[b + SP_LAST]
    s[b + SP_LAST] = value
    return value


@njit(**EXACT, inline="always")
def thermocouple_reading(s: np.ndarray, b: int, egt_k: float, z: float) -> float:
    """EGT reading (K): the probe lags the true EGT by one period, then noise z (standard
    normal); an open circuit reads its burnout value."""
    if s[b + TC_LAG] != 0.0:
        s[b + TC_PROBE] += (egt_k - s[b + TC_PROBE]) * s[b + TC_ALPHA]
    else:
        s[b + TC_PROBE] = egt_k
    if s[b + TC_OPEN] != 0.0:
        return s[b + TC_OPEN_K]
    return s[b + TC_PROBE] + s[b + TC_BIAS] + s[b + TC_NOISE] * z


class SpeedPickup:
    """Settings and fault switches of the speed pickup, in the state array ``s`` from ``b``."""

    def __init__(self, config: SpeedPickupConfig, s: np.ndarray, b: int) -> None:
        self.config = config
        self._s, self._b = s, b
        s[b + SP_RESOLUTION] = config.resolution_rpm
        s[b + SP_BIAS] = config.bias_rpm
        s[b + SP_DROPOUT_P] = config.dropout_probability
        s[b + SP_LAST] = 0.0
        self.dropout = False
        self.stuck = False
        self.burst_noise_rpm = 0.0

    @property
    def dropout(self) -> bool:
        return bool(self._s[self._b + SP_DROPOUT])

    @dropout.setter
    def dropout(self, on: bool) -> None:
        self._s[self._b + SP_DROPOUT] = 1.0 if on else 0.0

    @property
    def stuck(self) -> bool:
        return bool(self._s[self._b + SP_STUCK])

    @stuck.setter
    def stuck(self, on: bool) -> None:
        self._s[self._b + SP_STUCK] = 1.0 if on else 0.0

    @property
    def burst_noise_rpm(self) -> float:
        return self._burst

    @burst_noise_rpm.setter
    def burst_noise_rpm(self, rpm: float) -> None:
        self._burst = rpm
        self._s[self._b + SP_SIGMA] = math.hypot(self.config.noise_rpm, rpm)


class Thermocouple:
    """Settings, probe temperature and open-circuit switch of the thermocouple, in the state
    array ``s`` from ``b``; ``dt_s`` is the period between readings."""

    def __init__(
        self, config: ThermocoupleConfig, s: np.ndarray, b: int, t_initial_k: float, dt_s: float
    ) -> None:
        self.config = config
        self._s, self._b = s, b
        lag = config.time_constant_s > 0.0
        s[b + TC_LAG] = 1.0 if lag else 0.0
        s[b + TC_ALPHA] = 1.0 - math.exp(-dt_s / config.time_constant_s) if lag else 0.0
        s[b + TC_PROBE] = t_initial_k
        s[b + TC_BIAS] = config.bias_k
        s[b + TC_NOISE] = config.noise_k
        s[b + TC_OPEN_K] = config.open_circuit_k
        self.open_circuit = False

    @property
    def open_circuit(self) -> bool:
        return bool(self._s[self._b + TC_OPEN])

    @open_circuit.setter
    def open_circuit(self, on: bool) -> None:
        self._s[self._b + TC_OPEN] = 1.0 if on else 0.0
