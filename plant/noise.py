"""Seeded noise for the sensors: numpy's PCG64 drawn in blocks, so a reading costs no call into
numpy and a run with the same seed repeats bit for bit. The compiled period reads the blocks out
of the plant's state array (plant/periphery.py), which refills them from here."""

from __future__ import annotations

import numpy as np

BLOCK = 4096


class NoiseSource:
    """Blocks of standard normal and uniform [0, 1) samples from one seeded generator, in the
    order they are asked for."""

    def __init__(self, seed: int) -> None:
        if not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self._rng = np.random.Generator(np.random.PCG64(int(seed)))

    def normal_block(self) -> np.ndarray:
        return self._rng.standard_normal(BLOCK)

    def uniform_block(self) -> np.ndarray:
        return self._rng.random(BLOCK)
