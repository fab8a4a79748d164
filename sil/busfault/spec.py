"""Bus faults as a scenario states them (``[[bus_fault]]`` tables, see :mod:`sil.scenario`).

    [[bus_fault]]
    kind = "drop"            # drop | delay | duplicate | reorder | bitflip | freeze_counter
                             # | babble | bus_off
    ids = ["PlantSensors"]   # message names or frame IDs; bus_off without ids: every frame
    start_s = 20
    duration_s = 0.5
    rate = 1.0               # drop, duplicate, reorder, bitflip: probability per frame
    burst = 1                # drop: frames lost in a row once a loss starts
    delay_ticks = 2          # delay: ECU periods a frame is held, plus 0..jitter_ticks
    jitter_ticks = 0
    bits = 1                 # bitflip: payload bits flipped per frame (bytes 1..7, not the CRC)
    flood_per_tick = 4       # babble: frames of ids[0] with random payload per ECU period
    starve = true            # babble: frames of a higher ID (lower priority) do not get through
    # what the ECU must do (checked as invariants; all optional)
    detect = "E2E"           # "E2E": every corrupted frame rejected by its receiver's checker;
                             # or an ECU fault bit (ecu.faults.NAMES) set in EcuStatus
    within_ticks = 10        # ... within this many ECU periods of the window's start
    fallback_mode = "FAULT"  # the ECU mode reached during or after the fault
    recover_within_ticks = 50  # the detected bit clears this long after the window ends

Time is counted in ECU periods (ticks): a window covers ticks [start, start + duration).
"""

from __future__ import annotations

from dataclasses import dataclass

KINDS = ("drop", "delay", "duplicate", "reorder", "bitflip", "freeze_counter", "babble", "bus_off")
RATED = ("drop", "duplicate", "reorder", "bitflip")  # kinds that take a probability per frame
E2E_KINDS = ("bitflip", "freeze_counter")  # kinds whose frames an E2E checker must reject


@dataclass(frozen=True)
class Expectation:
    detect: str | None = None  # "E2E" or an ECU fault bit name
    within_ticks: int | None = None
    fallback_mode: str | None = None  # an ECU mode name (ecu.modes.NAMES)
    recover_within_ticks: int | None = None


@dataclass(frozen=True)
class BusFault:
    kind: str
    ids: tuple[int, ...]  # frame IDs affected; empty: every frame (bus_off only)
    start_s: float
    duration_s: float
    rate: float = 1.0
    burst: int = 1
    delay_ticks: int = 0
    jitter_ticks: int = 0
    bits: int = 1
    flood_per_tick: int = 1
    starve: bool = False
    expect: Expectation = Expectation()

    def window(self, rate_hz: float) -> tuple[int, int]:
        """First tick and the tick after the last one of the window."""
        start = int(round(self.start_s * rate_hz))
        return start, start + max(1, int(round(self.duration_s * rate_hz)))
