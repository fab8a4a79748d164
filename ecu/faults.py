"""Fault word bits (16 bits, reported in every status frame) and the sensor checks.

Speed sensor: range, rate (step per tick) and stuck checks, each with a persistence counter;
once failed, the speed is replaced by the fast-model observer (analytical redundancy) and the
failure is latched. EGT sensor: open circuit (reading railed high or low). Pump health: Lambda-hat
relative to its commissioning value, alarm below a threshold.
"""

from __future__ import annotations

from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import div_trunc
from ecu.state import EcuState

SPEED_RANGE = 1 << 0  # speed reading out of range
SPEED_RATE = 1 << 1  # speed reading jumps faster than the engine can
SPEED_STUCK = 1 << 2  # speed reading frozen while the pump voltage moved
SPEED_SUBSTITUTED = 1 << 3  # control runs on the fast-model estimate of speed
EGT_OPEN = 1 << 4  # EGT thermocouple open circuit
EGT_OVERTEMP = 1 << 5  # EGT above its maximum for too long (shutdown)
OVERSPEED = 1 << 6  # speed above the overspeed level for too long (shutdown)
FLAMEOUT = 1 << 7  # speed under idle by the margin, or the EGT under its floor, too long
PUMP_STALL = 1 << 8  # pump current too high (seized) or near zero (driver tripped)
PUMP_DRY = 1 << 9  # only the friction current with voltage applied: dry-running pump
PUMP_HEALTH = 1 << 10  # Lambda-hat under the alarm fraction of its commissioning value
DEMAND_LOST = 1 << 11  # demand frames missing beyond the hold time
SENSOR_FRAME_LOST = 1 << 12  # sensor frames missing or corrupt (speed/EGT substituted)
ANALOG_FRAME_LOST = 1 << 13  # analog frames missing (nominal supply voltage assumed)
LIMITER_ACTIVE = 1 << 14  # a limit loop owns the pump command (information)
PUMP_SATURATED = 1 << 15  # the pump voltage is at a limit (information)

NAMES = {
    SPEED_RANGE: "SPEED_RANGE",
    SPEED_RATE: "SPEED_RATE",
    SPEED_STUCK: "SPEED_STUCK",
    SPEED_SUBSTITUTED: "SPEED_SUBSTITUTED",
    EGT_OPEN: "EGT_OPEN",
    EGT_OVERTEMP: "EGT_OVERTEMP",
    OVERSPEED: "OVERSPEED",
    FLAMEOUT: "FLAMEOUT",
    PUMP_STALL: "PUMP_STALL",
    PUMP_DRY: "PUMP_DRY",
    PUMP_HEALTH: "PUMP_HEALTH",
    DEMAND_LOST: "DEMAND_LOST",
    SENSOR_FRAME_LOST: "SENSOR_FRAME_LOST",
    ANALOG_FRAME_LOST: "ANALOG_FRAME_LOST",
    LIMITER_ACTIVE: "LIMITER_ACTIVE",
    PUMP_SATURATED: "PUMP_SATURATED",
}
# bits that describe the current tick only; all others latch until re-initialisation
TRANSIENT = LIMITER_ACTIVE | PUMP_SATURATED | SENSOR_FRAME_LOST | ANALOG_FRAME_LOST | PUMP_HEALTH


def names(word: int) -> list[str]:
    """Names of the bits set in a fault word (for tools and reports, not the firmware path)."""
    return [name for bit, name in NAMES.items() if word & bit]


def persist(count: int, bad: int, limit: int) -> int:
    """Persistence counter: up by one while bad, down by one while good, held in [0, limit]
    (at 0 with a good reading it stays at 0: callers skip the call then)."""
    if bad:
        return count + 1 if count < limit else limit
    return count - 1 if count > 0 else 0


def speed_checks(s: EcuState, p: FirmwareParams, rpm: int, prev_rpm: int, v_q24: int) -> int:
    """Range, rate and stuck checks on a fresh speed reading; returns fault bits that tripped."""
    bad = rpm < 0 or rpm > p.speed_valid_max_rpm
    if bad or s.speed_range_cnt:
        s.speed_range_cnt = persist(s.speed_range_cnt, bad, p.speed_fault_ticks)
    step = rpm - prev_rpm
    bad = step > p.speed_step_max_rpm or step < -p.speed_step_max_rpm
    if bad or s.speed_rate_cnt:
        s.speed_rate_cnt = persist(s.speed_rate_cnt, bad, p.speed_fault_ticks)
    # stuck: reading frozen for the stuck time while the pump voltage has moved since it froze
    if rpm != prev_rpm:
        s.speed_stuck_cnt = 0
        s.speed_stuck_v_q24 = v_q24
    else:
        dv = v_q24 - s.speed_stuck_v_q24
        moved = dv > p.speed_stuck_dv_q24 or dv < -p.speed_stuck_dv_q24
        if moved or s.speed_stuck_cnt:
            s.speed_stuck_cnt = persist(s.speed_stuck_cnt, moved, p.speed_stuck_ticks)
    tripped = 0
    if s.speed_range_cnt >= p.speed_fault_ticks:
        tripped |= SPEED_RANGE
    if s.speed_rate_cnt >= p.speed_fault_ticks:
        tripped |= SPEED_RATE
    if s.speed_stuck_cnt >= p.speed_stuck_ticks:
        tripped |= SPEED_STUCK
    return tripped


def egt_open_check(s: EcuState, p: FirmwareParams, egt_dk: int) -> int:
    """Open thermocouple: reading railed above or below the plausible range, persistent."""
    bad = egt_dk > p.egt_open_high_dk or egt_dk < p.egt_open_low_dk
    if bad or s.egt_open_cnt:
        s.egt_open_cnt = persist(s.egt_open_cnt, bad, p.egt_fault_ticks)
    return EGT_OPEN if s.egt_open_cnt >= p.egt_fault_ticks else 0


def valid_readings(p: FirmwareParams, rpm: int, egt_dk: int) -> int:
    """The sensors whose fresh reading is plausible (ecu.firmware SEEN_* bits: 1 speed, 2 EGT):
    speed within its valid range, EGT not railed as an open thermocouple reads."""
    seen = 1 if 0 <= rpm <= p.speed_valid_max_rpm else 0
    if p.egt_open_low_dk <= egt_dk <= p.egt_open_high_dk:
        seen |= 2
    return seen


def pump_health_pm(lambda_q24: int, lambda_comm_q24: int) -> int:
    """Pump health in 0.1 % of the commissioning Lambda (eq. 4.3: fuel flow per volt)."""
    return div_trunc(lambda_q24 * 1000, lambda_comm_q24)
