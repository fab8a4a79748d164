"""Arm, throttle and stop of a bench with no autopilot: the checks and actions that the service
port and the XCP slave share, on one bench demand source (:mod:`ecu.service.bench_demand`).

Each front end checks its own unlock (the service port's session, XCP's CAL/PAG resource) and
then asks this module, which refuses what the ECU's state does not allow, with the reason:

- an arm in a latched FAULT, while a stop cools the engine down, or before the ECU has had valid
  speed and EGT readings (no engine node on the bus yet);
- a throttle outside 0 (idle) .. the demand's maximum, or while CAN Demand frames are present
  (they win while present);
- a stop is always accepted, and held until the next arm.

Before each tick :meth:`BenchControl.step` hands the firmware the inputs to take: the bench's
demand while the bench is the demand source, and the held stop.
"""

from __future__ import annotations

from collections.abc import Callable

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
        if not self.demand.can_present:
            self._take_demand("arm")
            self.demand.arm = 1
            self.demand.stop = 0

    def stop(self) -> None:
        """A stop request: always accepted, held until the next arm."""
        self.stop_held = True
        self.demand.arm = 0
        self.demand.stop = 1

    def throttle(self, pct: float) -> None:
        """The bench's speed demand, %N (0: idle); :class:`BenchRefused` says why not."""
        top = self.demand.max_cpct / 100
        if not 0 <= pct <= top:
            raise BenchRefused("OUT_OF_RANGE", f"pct={pct:g}: 0 (idle) .. {top:g} %N")
        self._take_demand("throttle")
        self.demand.set_throttle(round(pct * 100))
