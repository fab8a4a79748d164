"""Breakpoint tables on uniform speed axes, as the firmware reads them: linear between the
breakpoints, held beyond the ends (the PI's gain schedule, the fuel schedules)."""

from __future__ import annotations

from ecu.fixedpoint import div_trunc, sat32


def interp_uniform(table: tuple[int, ...], x0_q24: int, step_q24: int, x_q24: int) -> int:
    """table at x (Q7.24), its breakpoints at x0 + k step (k = 0 .. len(table) - 1)."""
    x = x_q24 - x0_q24
    if x <= 0:
        return table[0]
    last = len(table) - 1
    k = x // step_q24
    if k >= last:
        return table[last]
    f = x - k * step_q24
    return sat32(table[k] + div_trunc((table[k + 1] - table[k]) * f, step_q24))
