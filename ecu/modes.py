"""Mode logic: OFF -> ARMED -> RUN -> SHUTDOWN, with a latched FAULT.

- OFF: pump off. Arm request (and no stop request) -> ARMED; or straight to RUN when the engine
  is already running with a valid demand (warm start: the ECU was reset, or a SIL run starts
  at a trim point, and resumes control without cutting the fuel).
- ARMED: pump off, waiting for the starter to bring the engine to ``run_entry_pct`` with a valid
  demand (not older than the hold time) -> RUN. Losing the arm request or a stop request -> OFF.
- RUN: closed-loop control. Stop request, arm dropped, demand lost for 2 s or flameout ->
  SHUTDOWN. Overspeed, EGT over its maximum, pump stall or dry running, or sensor frames lost
  beyond their timeout -> FAULT.
- SHUTDOWN: pump off until the engine has spooled down and the arm request is released -> OFF.
- FAULT: pump off, latched until the ECU is re-initialised (power cycle, ``Ecu.reset``).
"""

from __future__ import annotations

OFF = 0
ARMED = 1
RUN = 2
SHUTDOWN = 3
FAULT = 4
NAMES = ("OFF", "ARMED", "RUN", "SHUTDOWN", "FAULT")


def next_mode(
    mode: int,
    arm: int,
    stop: int,
    running: int,
    demand_fresh: int,
    trip_fault: int,
    trip_shutdown: int,
    spooled_down: int,
) -> int:
    """The mode for this tick from the last mode and this tick's conditions."""
    if mode == FAULT:
        return FAULT
    if trip_fault and (mode == ARMED or mode == RUN):
        return FAULT
    if mode == OFF:
        if not arm or stop:
            return OFF
        return RUN if running and demand_fresh else ARMED
    if mode == ARMED:
        if stop or not arm:
            return OFF
        return RUN if running and demand_fresh else ARMED
    if mode == RUN:
        return SHUTDOWN if trip_shutdown or stop or not arm else RUN
    return OFF if spooled_down and not arm else SHUTDOWN
