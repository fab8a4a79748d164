"""Lockstep rules between the nodes, and the tick bookkeeping they share.

The plant owns simulated time (as in PX4/ArduPilot SITL). With ``k`` the tick (ECU period) number,
carried modulo 2**16 in SensorTick, ActuatorTick and DemandTick:

Plant, at tick k
    1. sends the frames due at k other than PlantSensors (PlantTruthA/B, PlantAnalog), then
       PlantSensors with SensorTick = k, always last;
    2. waits for EcuActuator with ActuatorTick = k (a wall-clock guard only protects against a dead
       ECU: a miss is counted, the last command is held, and after the pump driver's watchdog
       ticks the pump loses power);
    3. advances the engine one ECU period; k += 1.
Command node (scenario player)
    on PlantSensors(k) sends the Demand that applies from tick k + L (when due), with
    DemandTick = k + L, where L is :func:`demand_lead_ticks`, so that it is in flight well before
    it is needed. Before tick 0 it sends the demands for the due ticks below L.
ECU, on PlantSensors(k)
    1. if a Demand is due at k and lockstep demands are in use (a Demand with a tick was seen),
       waits for the Demand with DemandTick = k (same wall-clock guard);
    2. runs exactly one control step;
    3. sends EcuStatus and EcuTelemetry when due, then EcuActuator with ActuatorTick = k, last.

Every frame of a tick therefore precedes, on each sender's socket, the frame that releases the next
tick, and a run is the same at any speed. Frames due "every N ticks" follow the DBC cycle times at
the ECU rate (:func:`every_ticks`); a frame is due at tick k when k % N == 0.
"""

from __future__ import annotations

from enum import IntEnum

TICK_MODULO = 1 << 16


def every_ticks(cycle_time_ms: int, ecu_rate_hz: float) -> int:
    """How many ECU ticks apart a message with this DBC cycle time is sent (at least 1)."""
    if ecu_rate_hz <= 0:
        raise ValueError(f"ECU rate {ecu_rate_hz} Hz must be positive")
    return max(1, round(cycle_time_ms * ecu_rate_hz / 1000.0))


def demand_lead_ticks(demand_every: int) -> int:
    """How far ahead of its tick the command node sends a Demand: one demand period."""
    return demand_every


class TickEvent(IntEnum):
    NEXT = 0  # the expected tick
    REPEATED = 1  # the same tick again
    SKIPPED = 2  # ticks were missed in between
    OUT_OF_ORDER = 3  # an older tick


class TickTracker:
    """Classifies a stream of 16-bit tick numbers and counts what went wrong."""

    __slots__ = ("last", "repeated", "skipped", "missing", "out_of_order")

    def __init__(self) -> None:
        self.last = -1
        self.repeated = 0
        self.skipped = 0  # events
        self.missing = 0  # ticks lost in those events
        self.out_of_order = 0

    def observe(self, tick: int) -> TickEvent:
        if self.last < 0:
            self.last = tick % TICK_MODULO
            return TickEvent.NEXT
        delta = (tick - self.last) % TICK_MODULO
        if delta == 0:
            self.repeated += 1
            return TickEvent.REPEATED
        if delta >= TICK_MODULO // 2:
            self.out_of_order += 1
            return TickEvent.OUT_OF_ORDER
        self.last = tick % TICK_MODULO
        if delta == 1:
            return TickEvent.NEXT
        self.skipped += 1
        self.missing += delta - 1
        return TickEvent.SKIPPED
