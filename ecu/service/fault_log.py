"""The fault log: a ring of the latest events, each with its time, code and a snapshot.

Codes 0-15 are the bit numbers of the firmware's fault word (:mod:`ecu.faults`), logged when
the bit rises; codes from 64 are the service port's own events (parameter storage). The two
information bits (a limiter owns the command, the pump voltage is at a limit) are not logged.
The log lives in RAM and is cleared by the service or a power cycle.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from ecu import faults as F

CAPACITY = 32
PARAMS_DEFAULTS = 64  # no valid parameter slot in flash at start: defaults in use
PARAMS_REJECTED = 65  # a stored set (or some of its entries) was refused at start
LOGGED_BITS = 0xFFFF & ~(F.LIMITER_ACTIVE | F.PUMP_SATURATED)
SNAPSHOT_FIELDS = ("mode", "fault_word", "speed_cpct", "egt_dk", "pump_mv", "supply_mv", "pump_ma")


def code_name(code: int) -> str:
    if 0 <= code < 16:
        return F.NAMES[1 << code]
    return {PARAMS_DEFAULTS: "PARAMS_DEFAULTS", PARAMS_REJECTED: "PARAMS_REJECTED"}.get(
        code, f"CODE_{code}"
    )


@dataclass(frozen=True)
class FaultEntry:
    tick: int  # ECU ticks since power-up
    code: int
    snapshot: tuple[int, ...]  # SNAPSHOT_FIELDS

    def wire(self) -> list:
        return [self.tick, self.code, list(self.snapshot)]


class FaultLog:
    def __init__(self, capacity: int = CAPACITY) -> None:
        self.entries: deque[FaultEntry] = deque(maxlen=capacity)
        self.total = 0  # events logged since power-up (older ones roll off the ring)
        self._last_word = 0

    def record(self, tick: int, code: int, snapshot: tuple[int, ...]) -> None:
        self.entries.append(FaultEntry(tick, code, snapshot))
        self.total += 1

    def update(self, tick: int, fault_word: int, snapshot: tuple[int, ...]) -> None:
        """Log the fault bits that rose since the last call."""
        rising = fault_word & ~self._last_word & LOGGED_BITS
        self._last_word = fault_word
        bit = 0
        while rising:
            if rising & 1:
                self.record(tick, bit, snapshot)
            rising >>= 1
            bit += 1

    def clear(self) -> int:
        n = len(self.entries)
        self.entries.clear()
        return n
