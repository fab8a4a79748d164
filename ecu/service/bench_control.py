"""Arm, throttle and stop of a bench with no autopilot: the checks and actions that the service
port and the XCP slave share, on one bench demand source (:mod:`ecu.service.bench_demand`).

Each front end checks its own unlock (the service port's session, XCP's CAL/PAG resource) and
then asks this module, which refuses what the ECU's state does not allow, with the reason:

- an arm in a latched FAULT, while a stop cools the engine down, or before the ECU has had valid
  speed and EGT readings (no engine node on the bus yet);
- a throttle outside 0 (idle) .. the demand's maximum, or while CAN Demand frames are present
  (they win while present);
- a stop is always accepted, and held until the next arm.

A start always goes to idle: the bench's throttle is that of the run in progress, back to idle
when the engine leaves ARMED or RUN and when an arm starts it from rest.

Before each tick :meth:`BenchControl.step` hands the firmware the inputs to take: the bench's
demand while the bench is the demand source, and the held stop.
"""

from __future__ import annotations

from collections.abc import Callable

from ecu import actuator_tests as T
from ecu import modes as M
from ecu.firmware import Ecu, EcuInputs
from ecu.service import bench_demand as BD


class BenchRefused(ValueError):
    """A bench command the ECU refuses; ``reason`` is REFUSED (the ECU's state) or OUT_OF_RANGE,
    the message says why."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class BenchControl:
    """The bench demand source of one ECU and the stop it holds. ``on_switch(source)`` is told
    when the demand source switches (to ``bench_demand.CAN`` or ``BENCH``)."""

    def __init__(self, ecu: Ecu, on_switch: Callable[[int], None] | None = None) -> None:
        self.ecu = ecu
        self.demand = BD.BenchDemand(ecu.p)
        self.stop_held = False
        self.on_switch = on_switch
        # the bench test function requested (ecu.actuator_tests), its level and duration; the
        # request is dropped once the firmware has taken it and the test is over
        self.test_request = T.NONE
        self.test_level = 0
        self.test_ms = 0
        self._test_taken = False

    @property
    def source(self) -> int:
        return self.demand.source

    @property
    def source_name(self) -> str:
        return BD.SOURCE_NAMES[self.demand.source]

    def step(self, inputs: EcuInputs, ticking: bool = True) -> EcuInputs:
        """Before a tick: the inputs the firmware takes (``inputs``, or with the bench's demand
        while the bench is the source); with ``ticking`` False (no tick follows) only the held
        stop is applied."""
        ecu = self.ecu
        ticked = inputs
        if ticking:
            ticked, switched = self.demand.step(inputs, ecu.out.mode, ecu.s.rearm_wait)
            if switched is not None and self.on_switch is not None:
                self.on_switch(switched)
        if self.stop_held and not self.demand.engaged:
            inputs.stop = 1
            ecu.s.stop = 1
        if self._test_taken and ecu.s.test_active == T.NONE:
            self.test_request = T.NONE  # over (its time up, or ended by the firmware)
        self._test_taken = ticking and self.test_request != T.NONE
        for i in (inputs, ticked):
            i.test_request, i.test_level, i.test_ms = (
                self.test_request,
                self.test_level,
                self.test_ms,
            )
        return ticked

    def _take_demand(self, what: str) -> None:
        """Make the bench the demand source for ``what`` (refused while a CAN Demand is)."""
        bench = self.demand
        if bench.can_present:
            raise BenchRefused(
                "REFUSED",
                f"{what}: CAN Demand frames are the demand source (they win while present)",
            )
        if bench.engage(self.ecu.out.mode, BD.cpct(self.ecu.s.demand_q24)):
            if self.on_switch is not None:
                self.on_switch(BD.BENCH)

    def arm(self) -> None:
        """An arm request: the bench's arm (or, while a CAN Demand is present, the stop held
        released, its arm then applies); :class:`BenchRefused` says why not."""
        o = self.ecu.out
        if o.mode == M.FAULT:
            raise BenchRefused("REFUSED", "arm: latched FAULT (power-cycle the ECU)")
        if o.mode == M.SHUTDOWN:
            raise BenchRefused("REFUSED", "arm: the engine is stopping and cooling down")
        if not o.inputs_valid:
            raise BenchRefused(
                "REFUSED",
                "arm: no valid speed and EGT readings yet (is the engine's node on the bus?)",
            )
        self.stop_held = False
        self.test_request = T.NONE  # an arm ends a test
        if not self.demand.can_present:
            self._take_demand("arm")
            self.demand.request_arm(o.mode)

    def stop(self) -> None:
        """A stop request: always accepted, held until the next arm; it ends a test."""
        self.stop_held = True
        self.demand.arm = 0
        self.demand.stop = 1
        self.test_request = T.NONE

    def set_test(self, level: int | None = None, ms: int | None = None) -> None:
        """The next test's level (starter duty 0.01 %, pump mV) and duration (ms), checked
        when the test is asked for; :class:`BenchRefused` for a negative one."""
        for name, value in (("level", level), ("ms", ms)):
            if value is not None and value < 0:
                raise BenchRefused("OUT_OF_RANGE", f"test {name}={value}: not negative")
        self.test_level = self.test_level if level is None else level
        self.test_ms = self.test_ms if ms is None else ms

    def test(self, kind: int) -> None:
        """A bench test function (ecu.actuator_tests: 1 glow plug, 2 starter spin, 3 pump
        prime) at the level and for the time set, or 0: end the test. Refused outside OFF, with
        the arm held or while CAN Demand frames are present (REFUSED), and beyond its limits
        (OUT_OF_RANGE); the firmware refuses it too outside OFF."""
        if not T.NONE <= kind <= T.PRIME:
            raise BenchRefused("OUT_OF_RANGE", f"test={kind}: 0 (end), 1 glow, 2 starter, 3 prime")
        if kind == T.NONE:
            self.test_request = T.NONE
            return
        mode = self.ecu.out.mode
        if mode != M.OFF:
            raise BenchRefused("REFUSED", f"test: the ECU is in {M.NAMES[mode]}, not OFF")
        if self.demand.can_present or (self.demand.engaged and self.demand.arm):
            raise BenchRefused("REFUSED", "test: an arm or CAN Demand frames are present")
        p = self.ecu.p
        if not T.request_ok(p, kind, self.test_level, self.test_ms):
            top = T.level_max(p, kind)
            raise BenchRefused(
                "OUT_OF_RANGE",
                f"test {T.NAMES[kind]}: 1..{T.MAX_MS[kind]} ms"
                + (f", level 1..{top}" if kind != T.GLOW else ""),
            )
        self._take_demand("test")
        self.stop_held = False
        self.demand.stop = 0
        self.test_request = kind

    def throttle(self, pct: float) -> None:
        """The bench's speed demand, %N (0: idle); :class:`BenchRefused` says why not."""
        top = self.demand.max_cpct / 100
        if not 0 <= pct <= top:
            raise BenchRefused("OUT_OF_RANGE", f"pct={pct:g}: 0 (idle) .. {top:g} %N")
        self._take_demand("throttle")
        self.demand.set_throttle(round(pct * 100))
