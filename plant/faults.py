"""Faults and degradation, switched at a given simulated time.

A ``Fault`` says what happens, when (simulated seconds) and, for faults that end, for how long.
Health parameters follow NASA's engine models (C-MAPSS, T-MATS): scalars on the compressor and
turbine flow capacity and efficiency, 1.0 for a new engine. The document's failure scenario
(ch. 6) is ``Fault(30.0, FaultKind.PUMP_EFFECTIVENESS, 0.5)``.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from enum import StrEnum


class FaultKind(StrEnum):
    """Each kind's value is its name in scenario files and FaultInject frames (the DBC's
    FaultTarget, in lower case); PUMP_DRY and PUMP_STALL are the plant's own (no frame carries
    them)."""

    PUMP_EFFECTIVENESS = "pump_effectiveness"  # value: delivered / new-pump fuel, in [0, 1]
    PUMP_WEAR = "pump_wear_rate"  # value: effectiveness lost per second (gradual wear)
    PUMP_DRY = "pump_dry"  # runs dry: no fuel, friction current only
    PUMP_STALL = "pump_stall"  # gears seized: no fuel, driver trips, no current
    COMPRESSOR_EFFICIENCY = "compressor_efficiency"  # value: health scalar
    COMPRESSOR_FLOW = "compressor_flow"
    TURBINE_EFFICIENCY = "turbine_efficiency"
    TURBINE_FLOW = "turbine_flow"
    SPEED_DROPOUT = "speed_dropout"  # speed reads 0
    SPEED_STUCK = "speed_stuck"  # speed holds its last reading
    SPEED_NOISE_BURST = "speed_noise"  # value: extra noise, rpm (1 sigma)
    EGT_OPEN_CIRCUIT = "egt_open_circuit"  # thermocouple reads its upscale burnout value
    BATTERY_VOLTAGE = "supply_voltage"  # value: new open-circuit battery voltage, V
    AMBIENT_TEMPERATURE = "ambient_temperature"  # value: new ambient temperature T0, K
    STARTER_FAILURE = "starter_failure"  # value: torque left / a new starter's (0: dead motor)
    IGNITER_FAILURE = "igniter_failure"  # the glow plug is open: nothing lights
    FUEL_STARVATION = "fuel_starvation"  # value: the most the tank and line supply, kg/s


# kinds that need a value, with its allowed range
_VALUE_RANGE: dict[FaultKind, tuple[float, float]] = {
    FaultKind.PUMP_EFFECTIVENESS: (0.0, 1.0),
    FaultKind.PUMP_WEAR: (0.0, 1.0),
    FaultKind.COMPRESSOR_EFFICIENCY: (0.1, 1.5),
    FaultKind.COMPRESSOR_FLOW: (0.1, 1.5),
    FaultKind.TURBINE_EFFICIENCY: (0.1, 1.5),
    FaultKind.TURBINE_FLOW: (0.1, 1.5),
    FaultKind.SPEED_NOISE_BURST: (0.0, 1e5),
    FaultKind.BATTERY_VOLTAGE: (0.0, 100.0),
    FaultKind.AMBIENT_TEMPERATURE: (180.0, 340.0),
    FaultKind.STARTER_FAILURE: (0.0, 1.0),
    FaultKind.FUEL_STARVATION: (0.0, 1.0),
}


def value_range(kind: FaultKind) -> tuple[float, float] | None:
    """The values a fault of this kind takes (None: it takes no value)."""
    return _VALUE_RANGE.get(FaultKind(kind))


# DBC VAL_ FaultTarget -> what it does (0 = CLEAR_ALL is handled apart)
FAULT_TARGETS: dict[int, FaultKind] = {
    1: FaultKind.PUMP_EFFECTIVENESS,
    2: FaultKind.PUMP_WEAR,
    3: FaultKind.COMPRESSOR_EFFICIENCY,
    4: FaultKind.COMPRESSOR_FLOW,
    5: FaultKind.TURBINE_EFFICIENCY,
    6: FaultKind.TURBINE_FLOW,
    7: FaultKind.SPEED_DROPOUT,
    8: FaultKind.SPEED_STUCK,
    9: FaultKind.SPEED_NOISE_BURST,
    10: FaultKind.EGT_OPEN_CIRCUIT,
    11: FaultKind.BATTERY_VOLTAGE,
    12: FaultKind.AMBIENT_TEMPERATURE,
    13: FaultKind.IGNITER_FAILURE,
    14: FaultKind.STARTER_FAILURE,
    15: FaultKind.FUEL_STARVATION,
}
SWITCHED = (
    FaultKind.SPEED_DROPOUT,
    FaultKind.SPEED_STUCK,
    FaultKind.EGT_OPEN_CIRCUIT,
    FaultKind.IGNITER_FAILURE,
)  # 1 on, 0 off
ENDED_BY_ZERO = (FaultKind.SPEED_NOISE_BURST, FaultKind.PUMP_WEAR)
CLEAR_ALL = 0

# the faults the engine side handles (PlantBase._apply_engine); the fast model
# (plant.fast_plant), which has no compressor, turbine, starter, igniter or fuel supply, has none
ENGINE_FAULTS = (
    FaultKind.COMPRESSOR_EFFICIENCY,
    FaultKind.COMPRESSOR_FLOW,
    FaultKind.TURBINE_EFFICIENCY,
    FaultKind.TURBINE_FLOW,
    FaultKind.AMBIENT_TEMPERATURE,
    FaultKind.STARTER_FAILURE,
    FaultKind.IGNITER_FAILURE,
    FaultKind.FUEL_STARVATION,
)


def target_value_range(target: int) -> tuple[float, float] | None:
    """The values a FaultInject frame's FaultValue may carry for this FaultTarget for the plant
    node to apply it (PlantNode refuses others and counts them): the fault's own range, or None
    when any value does (CLEAR_ALL ignores it, a switched fault is off at 0 and on otherwise).
    KeyError for a target the plant does not know."""
    if target == CLEAR_ALL:
        return None
    kind = FAULT_TARGETS[target]
    return None if kind in SWITCHED else value_range(kind)


@dataclass(frozen=True, order=True)
class Fault:
    """``kind`` starts at ``at_s`` (simulated s); with ``duration_s`` it ends after that long."""

    at_s: float
    kind: FaultKind
    value: float | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", FaultKind(self.kind))
        if not math.isfinite(self.at_s) or self.at_s < 0.0:
            raise ValueError(f"fault at_s must be a finite time >= 0, got {self.at_s!r}")
        if self.duration_s is not None and (
            not math.isfinite(self.duration_s) or self.duration_s <= 0.0
        ):
            raise ValueError(f"fault duration_s must be finite and > 0, got {self.duration_s!r}")
        rng = _VALUE_RANGE.get(self.kind)
        if rng is None:
            if self.value is not None:
                raise ValueError(f"fault {self.kind.value} takes no value, got {self.value!r}")
            return
        if self.value is None or not math.isfinite(self.value):
            raise ValueError(f"fault {self.kind.value} needs a finite value, got {self.value!r}")
        if not rng[0] <= self.value <= rng[1]:
            raise ValueError(
                f"fault {self.kind.value} value must be in {list(rng)}, got {self.value}"
            )


class FaultSchedule:
    """Start and end events in time order; ``due(t)`` pops those at or before t. ``next_s`` is
    the time of the next event (inf when there is none): a step with ``next_s <= t + 1e-9``
    false has nothing due."""

    def __init__(self, faults: tuple[Fault, ...] | list[Fault] = ()) -> None:
        self._events: list[tuple[float, int, bool, Fault]] = []
        self._n = 0
        self.next_s = math.inf
        for f in faults:
            self.add(f)

    def add(self, fault: Fault) -> None:
        self._push(fault.at_s, True, fault)
        if fault.duration_s is not None:
            self._push(fault.at_s + fault.duration_s, False, fault)

    def _push(self, t: float, start: bool, fault: Fault) -> None:
        heapq.heappush(self._events, (t, self._n, start, fault))
        self._n += 1
        self.next_s = self._events[0][0]

    def due(self, t_s: float) -> list[tuple[Fault, bool]]:
        """Events with time <= t_s as (fault, starts) in order; an end has starts = False."""
        out = []
        while self._events and self._events[0][0] <= t_s + 1e-9:
            _, _, start, fault = heapq.heappop(self._events)
            out.append((fault, start))
        self.next_s = self._events[0][0] if self._events else math.inf
        return out
