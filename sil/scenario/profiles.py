"""Command profiles: steps, staircases, square and sine waves, ramps and CSV tables, summed.

Each component is a pure function of time; a profile is a base value plus the sum of its components,
sampled once per ECU tick (:func:`sample`).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Step:
    time_s: float
    value: float

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return np.where(t >= self.time_s, self.value, 0.0)


@dataclass(frozen=True)
class Staircase:
    levels: tuple[float, ...]
    step_s: float
    start_s: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        index = np.clip(((t - self.start_s) // self.step_s).astype(int), 0, len(self.levels) - 1)
        values = np.asarray(self.levels)[index]
        return np.where(t >= self.start_s, values, 0.0)


@dataclass(frozen=True)
class Square:
    amplitude: float
    frequency_hz: float
    start_s: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        phase = ((t - self.start_s) * self.frequency_hz) % 1.0
        wave = np.where(phase < 0.5, self.amplitude, -self.amplitude)
        return np.where(t >= self.start_s, wave, 0.0)


@dataclass(frozen=True)
class Sine:
    amplitude: float
    frequency_hz: float
    phase_deg: float = 0.0
    start_s: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * self.frequency_hz * (t - self.start_s) + np.radians(self.phase_deg)
        return np.where(t >= self.start_s, self.amplitude * np.sin(arg), 0.0)


@dataclass(frozen=True)
class Ramp:
    start_s: float
    end_s: float
    value: float

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return self.value * np.clip((t - self.start_s) / (self.end_s - self.start_s), 0.0, 1.0)


@dataclass(frozen=True)
class Table:
    """Linear interpolation in a CSV table of time and value, held beyond its ends."""

    times: tuple[float, ...]
    values: tuple[float, ...]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.times, self.values)

    @classmethod
    def from_csv(cls, path: Path, time_column: str, value_column: str) -> Table:
        times, values = [], []
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            for name in (time_column, value_column):
                if reader.fieldnames is None or name not in reader.fieldnames:
                    raise ValueError(f"{path}: no column '{name}' (columns: {reader.fieldnames})")
            for row in reader:
                line = reader.line_num
                try:
                    times.append(float(row[time_column]))
                    values.append(float(row[value_column]))
                except (TypeError, ValueError):
                    raise ValueError(
                        f"{path}, line {line}: '{row[time_column]}', '{row[value_column]}' "
                        "are not numbers"
                    ) from None
        if len(times) < 1:
            raise ValueError(f"{path}: no data rows")
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"{path}: column '{time_column}' must increase strictly")
        return cls(tuple(times), tuple(values))


Component = Step | Staircase | Square | Sine | Ramp | Table


@dataclass(frozen=True)
class Profile:
    base: float
    components: tuple[Component, ...]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        total = np.full_like(t, self.base, dtype=float)
        for component in self.components:
            total = total + component(t)
        return total


def tick_count(duration_s: float, rate_hz: float) -> int:
    """The last tick of a run of ``duration_s`` at ``rate_hz`` (its ticks are 0 .. this)."""
    return int(round(duration_s * rate_hz))


def sample(profile: Profile, duration_s: float, rate_hz: float) -> np.ndarray:
    """The profile at every ECU tick k = 0 .. tick_count (time k / rate)."""
    return profile(np.arange(tick_count(duration_s, rate_hz) + 1) / rate_hz)
