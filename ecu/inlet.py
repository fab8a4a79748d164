"""The day's inlet temperature, which the ECU has no sensor for.

It is the operator's ``inlet_temp_k`` until a start from rest reads a better one: before the
starter turns, a cold engine's thermocouple sits in still air at the day's temperature (small-
turbine ECUs show it as the ambient temperature). With ``inlet_from_egt`` the start takes the EGT
then as the day's temperature when it lies in ``INLET_RANGE_K`` (an engine still warm from a run
reads hotter and keeps the temperature it has). Two figures follow it:

    1 / sqrt(theta) = sqrt(T_std / T_inlet)     corrected speed N / sqrt(theta) of the schedules
    T_start = min(T_target T_inlet / T_std,     the start's EGT target: the same corrected
                  T_hot - margin)               temperature, under the hot-start limit

A hot day's engine runs hotter at every speed (the same corrected point at theta times the
temperature), a cold day's leaner: without them a hot day's start hangs under its target and a
cold day's deceleration floor sits at a lower corrected speed than the engine's. Temperatures in
0.01 K (ck) or 0.1 K (dk).
"""

from __future__ import annotations

from math import isqrt
from typing import TYPE_CHECKING

from ecu.params import INLET_MAX_DK, INLET_MIN_DK

if TYPE_CHECKING:
    from ecu.firmware_params import FirmwareParams
    from ecu.state import EcuState

T_STD_CK = 28815  # 288.15 K


def ncor_k_q24(inlet_ck: int) -> int:
    """1 / sqrt(theta) = sqrt(T_std / T_inlet) in Q24, the floor of the exact root."""
    return isqrt((T_STD_CK << 48) // inlet_ck)


def day_target_dk(target_dk: int, cap_dk: int, inlet_ck: int) -> int:
    """The start's EGT target on the day: the standard day's, times theta, under the cap."""
    return min(target_dk * inlet_ck // T_STD_CK, cap_dk)


def take_egt_at_rest(s: EcuState, p: FirmwareParams) -> None:
    """At a start from rest: the EGT read now as the day's temperature, if in range."""
    if p.inlet_from_egt and INLET_MIN_DK <= s.egt_dk <= INLET_MAX_DK:
        inlet_ck = s.egt_dk * 10
        s.ncor_k_q24 = ncor_k_q24(inlet_ck)
        s.seq_target_dk = day_target_dk(p.seq_egt_target_dk, p.seq_egt_cap_dk, inlet_ck)
