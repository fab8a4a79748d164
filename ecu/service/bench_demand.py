"""The bench demand source: the service port's throttle, arm and stop, for a bench with no
autopilot on the bus.

The CAN Demand frame wins while it is present (a valid one within the firmware's demand hold
time). Otherwise the bench is the demand source once an operator engages it, by an arm or a
throttle command on the service port; from then on, before each tick, it hands the firmware a
fresh demand (speed demand in 0.01 %N, arm, stop) as the CAN driver would, in its own copy of
the tick's inputs (the driver's record is left as the bus filled it). The switch between
the two is reported (the service port logs it) and bumpless: the bench takes over at the demand
and arm state in force, and a CAN Demand that comes back takes over where the engine is (the
reference model smooths its step).

The bench arm is one start request: it is dropped when the engine leaves ARMED or RUN (a stop,
an abort or a trip), so a start is never retried by itself. A stop holds until the next arm.
The bench's throttle belongs to one run: it goes back to idle when the engine leaves ARMED or
RUN and when an arm starts the engine from rest, so a start always goes to idle and a demand
set before the run (in an earlier one, or while the engine was at rest) is never taken.
"""

from __future__ import annotations

from ecu import modes as M
from ecu.firmware import E2E_OK, EcuInputs
from ecu.firmware_params import FirmwareParams

CAN = 0
BENCH = 1
NONE = 2
SOURCE_NAMES = ("CAN", "BENCH", "NONE")


def cpct(x_q24: int) -> int:
    """Q7.24 %N -> 0.01 %N per count, rounded."""
    return (x_q24 * 100 + (1 << 23)) >> 24


def running(mode: int) -> bool:
    """The engine is being started or runs (the modes a bench arm holds)."""
    return mode == M.ARMED or mode == M.RUN


class BenchDemand:
    """Which demand source is in force, and the bench's own demand."""

    def __init__(self, p: FirmwareParams) -> None:
        self.hold_ticks = p.demand_hold_ticks
        self.idle_cpct = cpct(p.idle_q24)
        self.max_cpct = cpct(p.demand_max_q24)
        self.engaged = False
        self.throttle_cpct = self.idle_cpct
        self.arm = 0
        self.stop = 0
        self.can_age = 1 << 30  # ticks since the last valid CAN Demand (never: large)
        self.can_cpct = self.idle_cpct  # the last CAN Demand's values
        self.can_arm = 0
        self._last_mode = M.OFF
        self._inputs = EcuInputs()  # the tick's inputs with the bench's demand

    @property
    def can_present(self) -> bool:
        return self.can_age <= self.hold_ticks

    @property
    def source(self) -> int:
        if self.can_present:
            return CAN
        return BENCH if self.engaged else NONE

    def engage(self, mode: int, demand_cpct: int) -> bool:
        """Take over as the demand source (an operator's command); bumpless: at the demand in
        force, and with the arm held while the engine runs. True when it just took over."""
        if self.engaged:
            return False
        self.engaged = True
        self.arm = 1 if running(mode) else 0
        self.stop = 0
        self.throttle_cpct = demand_cpct if running(mode) else self.idle_cpct
        return True

    def request_arm(self, mode: int) -> None:
        """An arm (the bench is the source): a start from rest begins at idle."""
        if not running(mode):
            self.throttle_cpct = self.idle_cpct
        self.arm = 1
        self.stop = 0

    def set_throttle(self, cpct: int) -> None:
        self.throttle_cpct = max(self.idle_cpct, min(cpct, self.max_cpct))

    def step(self, i: EcuInputs, mode: int, rearm_wait: int) -> tuple[EcuInputs, int | None]:
        """Before a tick: note the CAN Demand in ``i``; the inputs the firmware takes (``i``, or
        while the bench is the source its copy with the bench's demand) and the source it
        switched to (CAN or BENCH, else None). ``mode``: the ECU's mode after the last tick."""
        switched = None
        if i.demand_status == E2E_OK:
            self.can_age = 0
            self.can_cpct, self.can_arm = i.demand_cpct, i.arm
        elif self.can_age < 1 << 30:
            self.can_age += 1
        if self.engaged and self.can_present:
            self.engaged = False  # the CAN Demand wins while present
            switched = CAN
        left_run = running(self._last_mode) and not running(mode)
        self._last_mode = mode
        if left_run:
            self.throttle_cpct = self.idle_cpct  # the run's demand ends with the run
        if not self.engaged:
            return i, switched
        if left_run:
            self.arm = 0  # the start request is done: no retry by itself
        b = self._inputs
        for name in EcuInputs.FIELDS:
            setattr(b, name, getattr(i, name))
        b.demand_cpct = self.throttle_cpct
        b.open_loop_mv = 0
        # a fresh arm after a run that ended with the arm held: released for one tick first
        b.arm = 0 if rearm_wait else self.arm
        b.stop = self.stop
        b.demand_status = E2E_OK
        return b, switched
