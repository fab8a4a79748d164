"""The fault log: a ring of the latest events, each with its time, code and a snapshot.

Codes 0-15 are the bit numbers of the firmware's fault word (:mod:`ecu.faults`), logged when
the bit rises; codes from 64 are the service port's own events (parameter storage); code
START_ABORT + r is a start aborted with reason r (:mod:`ecu.start_sequencer`: 1
IGNITION_TIMEOUT ... 6 STOPPED), logged when the abort happens, with the sequencer's state in
the snapshot. The two
information bits (a limiter owns the command, the pump voltage is at a limit) are not logged.
An event that repeats one of the last REPEAT_WINDOW entries is counted on that entry (its
count and the tick of its latest repeat) instead of taking a new one, so that a burst of repeats
never pushes older events out of the ring. The log lives in RAM and is cleared by the service
or a power cycle.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from ecu import faults as F
from ecu import start_sequencer as Q

CAPACITY = 32
PARAMS_DEFAULTS = 64  # no valid parameter slot in flash at start: defaults in use
PARAMS_REJECTED = 65  # a stored set (or some of its entries) was refused at start
DEMAND_SOURCE_CAN = 66  # the CAN Demand took over as the demand source
DEMAND_SOURCE_BENCH = 67  # the service port's bench demand took over
OTHER_ECU = 68  # another ECU on the bus: frames of this ECU's IDs from another sender
REPEAT_WINDOW = 4
START_ABORT = 80  # + the abort reason
LOGGED_BITS = 0xFFFF & ~(F.LIMITER_ACTIVE | F.PUMP_SATURATED)
SNAPSHOT_FIELDS = (
    "mode", "fault_word", "speed_cpct", "egt_dk", "pump_mv", "supply_mv", "pump_ma", "seq_state",
)  # fmt: skip


def code_name(code: int) -> str:
    if 0 <= code < 16:
        return F.NAMES[1 << code]
    if START_ABORT < code < START_ABORT + len(Q.REASONS):
        return f"START_ABORT_{Q.REASONS[code - START_ABORT]}"
    return {
        PARAMS_DEFAULTS: "PARAMS_DEFAULTS",
        PARAMS_REJECTED: "PARAMS_REJECTED",
        DEMAND_SOURCE_CAN: "DEMAND_SOURCE_CAN",
        DEMAND_SOURCE_BENCH: "DEMAND_SOURCE_BENCH",
        OTHER_ECU: "OTHER_ECU_ON_BUS",
    }.get(code, f"CODE_{code}")


@dataclass
class FaultEntry:
    tick: int  # ECU ticks since power-up, at the first occurrence
    code: int
    snapshot: tuple[int, ...]  # SNAPSHOT_FIELDS, at the first occurrence
    count: int = 1  # occurrences counted on this entry
    last_tick: int = -1  # tick of the latest repeat (the first's when none)

    def __post_init__(self) -> None:
        if self.last_tick < 0:
            self.last_tick = self.tick

    def wire(self) -> list:
        return [self.tick, self.code, list(self.snapshot), self.count, self.last_tick]


class FaultLog:
    def __init__(self, capacity: int = CAPACITY) -> None:
        self.entries: deque[FaultEntry] = deque(maxlen=capacity)
        self.total = 0  # events logged since power-up (older ones roll off the ring)
        self._last_word = 0
        self._last_reason = 0

    def record(self, tick: int, code: int, snapshot: tuple[int, ...]) -> None:
        self.total += 1
        for k in range(1, min(REPEAT_WINDOW, len(self.entries)) + 1):
            entry = self.entries[-k]
            if entry.code == code:  # a repeat: counted, not a new entry
                entry.count += 1
                entry.last_tick = tick
                return
        self.entries.append(FaultEntry(tick, code, snapshot))

    def update(
        self, tick: int, fault_word: int, snapshot: tuple[int, ...], abort_reason: int = 0
    ) -> None:
        """Log the fault bits that rose since the last call, and a start abort (a new reason)."""
        if abort_reason and abort_reason != self._last_reason:
            self.record(tick, START_ABORT + abort_reason, snapshot)
        self._last_reason = abort_reason
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
