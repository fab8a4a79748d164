"""Pump driver: pump voltage command -> PWM duty using the measured supply (battery sag
compensation), within duty limits; pump current checks for a stalled or dry-running pump.

    duty = V_cmd / V_supply   (0.01 % per count, truncated toward zero, clamped to the limits)
"""

from __future__ import annotations

from ecu.faults import PUMP_DRY, PUMP_STALL, persist
from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import clamp, div_trunc
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
    """Stall (current high: seized; or near zero: the driver tripped) and dry running (only the
    friction current), with voltage applied, each persistent."""
    applied = v_q24 > p.pump_dry_min_q24
    stall = pump_ma > p.pump_stall_ma or (applied and pump_ma < p.pump_trip_ma)
    if stall or s.pump_stall_cnt:
        s.pump_stall_cnt = persist(s.pump_stall_cnt, stall, p.pump_stall_ticks)
    v_mv = volts_q24_to_mv(v_q24)
    dry_ma = p.pump_dry_base_ma + div_trunc(p.pump_dry_ma_per_v * v_mv, 1000)
    dry = applied and p.pump_trip_ma <= pump_ma < dry_ma
    if dry or s.pump_dry_cnt:
        s.pump_dry_cnt = persist(s.pump_dry_cnt, dry, p.pump_dry_ticks)
    tripped = 0
    if s.pump_stall_cnt >= p.pump_stall_ticks:
        tripped |= PUMP_STALL
    if s.pump_dry_cnt >= p.pump_dry_ticks:
        tripped |= PUMP_DRY
    return tripped
