"""Seeded noise for the sensors: numpy's PCG64 drawn in blocks, so a reading costs no call into
numpy and a run with the same seed repeats bit for bit."""

from __future__ import annotations

import numpy as np

BLOCK = 4096


class NoiseSource:
    """Standard normal and uniform [0, 1) samples from one seeded generator."""

    def __init__(self, seed: int) -> None:
        if not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self._rng = np.random.Generator(np.random.PCG64(int(seed)))
        self._normal: list[float] = []
        self._uniform: list[float] = []

    def normal(self) -> float:
        if not self._normal:
            self._normal = self._rng.standard_normal(BLOCK).tolist()[::-1]
        return self._normal.pop()

    def uniform(self) -> float:
        if not self._uniform:
            self._uniform = self._rng.random(BLOCK).tolist()[::-1]
        return self._uniform.pop()
