"""Pump driver: pump voltage command -> PWM duty using the measured supply (battery sag
compensation), within duty limits; pump current checks for a stalled or dry-running pump.

    duty = V_cmd / V_supply   (0.01 % per count, truncated toward zero, clamped to the limits)
"""

from __future__ import annotations

from ecu.faults import PUMP_DRY, PUMP_STALL, persist
from ecu.fixedpoint import clamp, div_trunc
from ecu.params import FirmwareParams
from ecu.state import EcuState


def volts_q24_to_mv(v_q24: int) -> int:
    """Q7.24 volts -> millivolts, rounded to nearest."""
    return (v_q24 * 1000 + (1 << 23)) >> 24


def pump_duty(s: EcuState, p: FirmwareParams, v_mv: int, supply_mv: int) -> int:
    """Duty in 0.01 % for v_mv at the measured supply; a clipped duty sets s.v_saturated."""
    duty = div_trunc(v_mv * 10000, supply_mv) if supply_mv > 0 else p.duty_max_cpct
    limited = clamp(duty, p.duty_min_cpct, p.duty_max_cpct)
    if limited != duty:
        s.v_saturated = 1
    return limited


def pump_current_checks(s: EcuState, p: FirmwareParams, pump_ma: int, v_q24: int) -> int:
    """Stall (current high) and dry running (current low with voltage applied), persistent."""
    s.pump_stall_cnt = persist(s.pump_stall_cnt, pump_ma > p.pump_stall_ma, p.pump_stall_ticks)
    dry = pump_ma < p.pump_dry_ma and v_q24 > p.pump_dry_min_q24
    s.pump_dry_cnt = persist(s.pump_dry_cnt, dry, p.pump_dry_ticks)
    tripped = 0
    if s.pump_stall_cnt >= p.pump_stall_ticks:
        tripped |= PUMP_STALL
    if s.pump_dry_cnt >= p.pump_dry_ticks:
        tripped |= PUMP_DRY
    return tripped
