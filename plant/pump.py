"""Gear-type fuel pump (sec. 2.2) and its driver: fuel flow as a 2-D lookup of pump voltage and
outlet pressure, pump current, and a battery that sags with load.

The motor's dynamics (milliseconds) are neglected against the engine's (seconds), as in the
document, so the pump is algebraic. Outlet pressure = compressor delivery pressure P3 plus the
injector pressure drop; the table is in gauge pressure (above ambient), as fig. 2.8 is.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import numpy as np
from numba import njit

from plant.jit import JIT
from plant.lookup import interp2


class PumpTable(NamedTuple):
    """Fuel flow [voltage, outlet gauge pressure] in kg/s, and the current model of fig. 2.8."""

    voltage: np.ndarray  # V
    pressure: np.ndarray  # outlet gauge pressure, Pa
    flow: np.ndarray  # kg/s
    current_idle_a: float  # no-load current (friction), A
    current_per_volt: float  # viscous part, A/V
    current_per_pa: float  # pumping torque, A/Pa of outlet gauge pressure


class PumpState(IntEnum):
    """What the pump mechanism is doing (faults switch it)."""

    NORMAL = 0
    DRY = 1  # runs dry: no fuel, no pressure, only friction current
    STALLED = 2  # gears seized: the driver's over-current trip cuts the motor, no flow, no current


@njit(**JIT, inline="always")
def pump_flow(
    v_pump: float, p_out_gauge_pa: float, table: PumpTable, effectiveness: float
) -> tuple[float, bool]:
    """(fuel flow kg/s, clamped) at pump voltage and outlet gauge pressure; effectiveness in [0, 1]
    scales the delivery (wear, the document's failure halves it)."""
    q, clamped = interp2(table.voltage, table.pressure, table.flow, v_pump, p_out_gauge_pa)
    return effectiveness * max(q, 0.0), clamped


def pump_current(v_pump: float, p_out_gauge_pa: float, table: PumpTable, state: PumpState) -> float:
    """Motor current (A): friction plus the torque to pump against outlet pressure (fig. 2.8)."""
    if state == PumpState.STALLED or v_pump <= 0.0:
        return 0.0
    friction = table.current_idle_a + table.current_per_volt * v_pump
    if state == PumpState.DRY:
        return friction
    return friction + table.current_per_pa * max(p_out_gauge_pa, 0.0)


def supply_and_pump_voltage(
    duty: float,
    battery_v: float,
    battery_r_ohm: float,
    p_out_gauge_pa: float,
    table: PumpTable,
    state: PumpState,
) -> tuple[float, float, float]:
    """(supply voltage, pump voltage, pump current) with V_pump = duty * V_supply and
    V_supply = V_battery - R_internal * I_pump, I_pump affine in V_pump (solved in closed form)."""
    if state == PumpState.STALLED or duty <= 0.0:
        return battery_v, 0.0, 0.0
    load = table.current_idle_a
    if state != PumpState.DRY:
        load += table.current_per_pa * max(p_out_gauge_pa, 0.0)
    v_pump = (
        duty
        * (battery_v - battery_r_ohm * load)
        / (1.0 + duty * battery_r_ohm * table.current_per_volt)
    )
    v_pump = max(v_pump, 0.0)
    current = pump_current(v_pump, p_out_gauge_pa, table, state)
    return battery_v - battery_r_ohm * current, v_pump, current
