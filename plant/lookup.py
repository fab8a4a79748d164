"""Linear interpolation in 1-D and 2-D tables on evenly spaced axes, clamping at the edges and
saying when it did.

Maps queried outside their tables clamp to the edge value; the caller turns the returned flag into
a plant flag, so an engine driven off its maps is visible instead of silently extrapolated. Axes
are evenly spaced (checked by ``check_axis`` when tables are loaded), so locating a point is one
division instead of a search.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from plant.jit import JIT


def check_axis(name: str, axis: np.ndarray) -> None:
    """Raise ValueError unless axis is 1-D, increasing and evenly spaced."""
    d = np.diff(axis)
    if axis.ndim != 1 or axis.size < 2 or np.any(d <= 0) or np.ptp(d) > 1e-9 * abs(d[0]) + 1e-12:
        raise ValueError(f"table axis {name} must be increasing and evenly spaced")


@njit(**JIT, inline="always")
def locate(axis: np.ndarray, x: float) -> tuple[int, float, bool]:
    """Index i and weight w with x = (1 - w) axis[i] + w axis[i + 1]; clamped if outside."""
    n = axis.shape[0]
    if x <= axis[0]:
        return 0, 0.0, x < axis[0]
    if x >= axis[n - 1]:
        return n - 2, 1.0, x > axis[n - 1]
    step = axis[1] - axis[0]
    i = min(int((x - axis[0]) / step), n - 2)
    return i, (x - axis[i]) / step, False


@njit(**JIT, inline="always")
def interp1(axis: np.ndarray, values: np.ndarray, x: float) -> tuple[float, bool]:
    """values(x) by linear interpolation; (value, clamped)."""
    i, w, clamped = locate(axis, x)
    return (1.0 - w) * values[i] + w * values[i + 1], clamped


@njit(**JIT, inline="always")
def interp2_at(table: np.ndarray, i: int, wx: float, j: int, wy: float) -> float:
    """Bilinear interpolation of table at the cell (i, j) with weights (wx, wy) from ``locate``."""
    v0 = (1.0 - wy) * table[i, j] + wy * table[i, j + 1]
    v1 = (1.0 - wy) * table[i + 1, j] + wy * table[i + 1, j + 1]
    return (1.0 - wx) * v0 + wx * v1


@njit(**JIT, inline="always")
def interp2(
    x_axis: np.ndarray, y_axis: np.ndarray, table: np.ndarray, x: float, y: float
) -> tuple[float, bool]:
    """table[i, j] at (x_axis[i], y_axis[j]) interpolated bilinearly at (x, y); (value, clamped)."""
    i, wx, cx = locate(x_axis, x)
    j, wy, cy = locate(y_axis, y)
    return interp2_at(table, i, wx, j, wy), cx or cy
