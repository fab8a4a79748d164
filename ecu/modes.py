"""Mode logic: OFF -> ARMED -> RUN -> SHUTDOWN, with a latched FAULT.

- OFF: pump off. Arm request (and no stop request) -> ARMED; or straight to RUN when the engine
  is already running with a valid demand (warm start: the ECU was reset, or a SIL run starts
  at a trim point, and resumes control without cutting the fuel). Neither before the ECU is
  ready: valid speed and EGT readings since power-up, a fresh demand, and, after a start or a
  run that ended with the arm request held, that request released once (no start is retried
  by itself). So RUN always follows real readings: a flameout needs a real running history.
- ARMED: the start sequencer (ecu.start_sequencer, with ``start_on``) starts the engine from
  rest; at idle with a valid demand (not older than the hold time) -> RUN. Without the
  sequencer, pump off, waiting for an external starter to bring the engine to ``run_entry_pct``.
  Losing the arm request, a stop request or a demand lost for 2 s -> SHUTDOWN once fuel went in
  (to cool down), else OFF; a start abort -> SHUTDOWN.
- RUN: closed-loop control. Stop request, arm dropped, demand lost for 2 s or flameout ->
  SHUTDOWN (a flameout -> ARMED instead while relight attempts remain: the sequencer relights).
  Overspeed, EGT over its maximum, pump stall or dry running, or sensor frames lost beyond their
  timeout -> FAULT.
- SHUTDOWN: pump off, the sequencer's cool-down; once spooled down and cool and the arm request
  is released -> OFF.
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
    fuelled: int = 0,
    relight: int = 0,
    cooled: int = 1,
    ready: int = 1,
) -> int:
    """The mode for this tick from the last mode and this tick's conditions. With the start
    sequencer: fuelled, the start has put fuel in (leaving ARMED then goes through SHUTDOWN and
    its cool-down); relight, a flameout in RUN goes back to ARMED to relight; cooled, the
    cool-down is done (SHUTDOWN -> OFF waits for it); ready, the ECU may leave OFF (valid
    readings, a fresh demand, no arm request left over from the last start)."""
    if mode == FAULT:
        return FAULT
    if trip_fault and (mode == ARMED or mode == RUN):
        return FAULT
    if mode == OFF:
        if not arm or stop or not ready:
            return OFF
        return RUN if running and demand_fresh else ARMED
    if mode == ARMED:
        if stop or not arm or trip_shutdown:
            return SHUTDOWN if fuelled else OFF
        return RUN if running and demand_fresh else ARMED
    if mode == RUN:
        if relight and arm and not stop:
            return ARMED
        return SHUTDOWN if trip_shutdown or stop or not arm else RUN
    return OFF if spooled_down and cooled and not arm else SHUTDOWN
