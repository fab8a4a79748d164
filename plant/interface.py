"""The plant's interface around one ECU period, shared by both plants (Embedded Coder / PX4 style):
parameters in ``PlantConfig``, inputs as the arguments of ``step``, outputs in one reused
``PlantOutputs`` record, state inside the plant. Simulated time is counted by the plant in ECU
periods (lockstep: the plant owns time); nothing reads the wall clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

from plant.faults import Fault, FaultKind
from plant.sensors import SpeedPickupConfig, ThermocoupleConfig

SUBSTEP_S = 0.001  # RK4 step (sec. 2.3)
HEALTH_FIELDS = ("compressor_efficiency", "compressor_flow", "turbine_efficiency", "turbine_flow")


def check_finite(
    name: str, value: float, minimum: float | None = None, maximum: float | None = None
) -> float:
    """value as float, or ValueError naming the field when it is NaN, infinite or out of range."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if minimum is not None and v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    if maximum is not None and v > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {value!r}")
    return v


@dataclass(frozen=True)
class Ambient:
    """Engine inlet conditions; default: the document's sea-level static test bench (sec. 2.3)."""

    t0_k: float = 288.15
    p0_pa: float = 101325.0
    flight_speed_m_s: float = 0.0

    def __post_init__(self) -> None:
        check_finite("ambient t0_k", self.t0_k, 180.0, 340.0)
        check_finite("ambient p0_pa", self.p0_pa, 10000.0, 110000.0)
        check_finite("ambient flight_speed_m_s", self.flight_speed_m_s, 0.0, 300.0)


@dataclass(frozen=True)
class Battery:
    """Pump supply: open-circuit voltage and internal resistance (sags with pump current).
    Default: a 6S lithium-polymer pack at nominal voltage."""

    voltage_v: float = 22.2
    internal_resistance_ohm: float = 0.05

    def __post_init__(self) -> None:
        check_finite("battery voltage_v", self.voltage_v, 0.0, 100.0)
        check_finite("battery internal_resistance_ohm", self.internal_resistance_ohm, 0.0, 10.0)


@dataclass(frozen=True)
class PlantConfig:
    """Parameters of a plant run."""

    ecu_period_s: float = 0.01  # one step() advances this much, in SUBSTEP_S RK4 steps
    ambient: Ambient = field(default_factory=Ambient)
    battery: Battery = field(default_factory=Battery)
    initial_fuel_kg_s: float = 0.008  # start at the steady state of this fuel flow (eq. 2.33)
    # or, when set, at the steady state holding this speed (%N), or the fastest one within
    # initial_egt_max_k if that speed is hotter: each varied engine where its governor holds it
    initial_speed_pct: float | None = None
    initial_egt_max_k: float = math.inf
    # or, when set, at rest: 0 rpm, ambient pressures and temperatures, no flame, no fuel
    # pooled (a start from standstill; aero-thermal plant only)
    standstill: bool = False
    # the hot section's thermal mass (plant/hot_section.py; aero-thermal plant): None = with a
    # start from rest, without (the metal always at the gas temperature: the document's engine,
    # whose figures are reproduced exactly) for a start in steady state
    hot_section: bool | None = None
    faults: tuple[Fault, ...] = ()
    seed: int = 0
    speed_pickup: SpeedPickupConfig = field(default_factory=SpeedPickupConfig)
    thermocouple: ThermocoupleConfig = field(default_factory=ThermocoupleConfig)
    overspeed_pct: float = 100.0  # reported above this speed (rated maximum, 112,500 rpm)
    overtemperature_egt_k: float = 1300.0  # reported above this EGT (see plant/__init__.py)
    # engine-to-engine variation, as built (the initial steady state is solved with it): health
    # scalars of the compressor and turbine maps (aero-thermal plant only) and the pump's gain
    # (delivered / table fuel flow, the new pump's effectiveness), all 1.0 for the nominal engine
    compressor_efficiency: float = 1.0
    compressor_flow: float = 1.0
    turbine_efficiency: float = 1.0
    turbine_flow: float = 1.0
    pump_gain: float = 1.0

    def __post_init__(self) -> None:
        check_finite("ecu_period_s", self.ecu_period_s, SUBSTEP_S, 1.0)
        n = self.ecu_period_s / SUBSTEP_S
        if abs(n - round(n)) > 1e-9:
            raise ValueError(
                f"ecu_period_s must be a multiple of {SUBSTEP_S} s, got {self.ecu_period_s}"
            )
        check_finite("initial_fuel_kg_s", self.initial_fuel_kg_s, 1e-4, 0.05)
        if self.initial_speed_pct is not None:
            check_finite("initial_speed_pct", self.initial_speed_pct, 10.0, 120.0)
        if not (math.isinf(self.initial_egt_max_k) or 300.0 <= self.initial_egt_max_k <= 2500.0):
            raise ValueError(
                f"initial_egt_max_k must be in [300, 2500] K, got {self.initial_egt_max_k!r}"
            )
        check_finite("overspeed_pct", self.overspeed_pct, 0.0)
        check_finite("overtemperature_egt_k", self.overtemperature_egt_k, 0.0)
        for name in HEALTH_FIELDS:
            check_finite(name, getattr(self, name), 0.1, 1.5)
        check_finite("pump_gain", self.pump_gain, 0.1, 2.0)
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")

    @property
    def hot_section_mass(self) -> bool:
        """The hot section's thermal mass is simulated (``hot_section``, by default with a start
        from rest)."""
        return self.standstill if self.hot_section is None else self.hot_section

    @property
    def substeps(self) -> int:
        return int(round(self.ecu_period_s / SUBSTEP_S))


@dataclass(slots=True)
class PlantOutputs:
    """One ECU period's outputs: sensor readings (what the ECU sees) and truth (for logging)."""

    tick: int = 0  # ECU periods simulated so far
    time_s: float = 0.0  # simulated time at the end of the period
    # sensors
    speed_rpm: float = 0.0  # speed pickup reading
    egt_k: float = 0.0  # thermocouple reading
    supply_v: float = 0.0  # pump supply (battery) voltage under load
    pump_current_a: float = 0.0
    # truth
    n_rpm: float = 0.0
    n_pct: float = 0.0
    p3_pa: float = 0.0
    p5_pa: float = 0.0
    t4_k: float = 0.0
    egt_true_k: float = 0.0  # gas leaving the hot section (T5 = T6 of eq. 2.24 when steady)
    fuel_kg_s: float = 0.0
    air_kg_s: float = 0.0
    thrust_n: float = 0.0
    pump_v: float = 0.0  # voltage at the pump terminals = duty x supply voltage
    pump_effectiveness: float = 1.0
    starter_current_a: float = 0.0  # drawn from the battery by the starter
    hot_section_k: float = 0.0  # the hot section's metal temperature
    unburnt_fuel_kg: float = 0.0  # fuel the pump delivered while no flame burnt, since the start
    burning: float = 1.0  # 1 while the flame burns
    flags: int = 0  # plant.flags bits (decode with plant.flags.PlantFlag)


class Plant(Protocol):
    """What the SIL harness and the CAN node need from a plant (AeroThermalPlant, FastPlant)."""

    config: PlantConfig
    outputs: PlantOutputs  # the record step() updates in place and returns
    trim_pump_voltage: float  # pump voltage holding the initial steady state
    trim_duty: float  # duty giving that voltage from the configured battery

    @property
    def time_s(self) -> float:
        """Simulated time: ECU periods stepped so far times the period."""
        ...

    def step(
        self,
        pump_duty: float,
        pump_enabled: bool = True,
        starter_duty: float = 0.0,
        igniter: bool = False,
    ) -> PlantOutputs:
        """Advance one ECU period with the pump at ``pump_duty`` (0..1) of the supply voltage,
        the starter at ``starter_duty`` (0..1) and the igniter on or off."""
        ...

    @property
    def starter_command(self) -> tuple[float, bool]:
        """The starter's duty (0..1) and the igniter's power as the plant runs them now."""
        ...

    def set_starter(self, starter_duty: float, igniter: bool) -> None:
        """The starter's duty (0..1) and the igniter's power from now on (a step() sets them
        for its period)."""
        ...

    def inject(self, fault: Fault) -> None:
        """Schedule a fault (``fault.at_s`` in simulated seconds; past times apply at once)."""
        ...

    def end_fault(self, kind: FaultKind) -> None:
        """End a fault of this kind now."""
        ...

    def clear_faults(self) -> None:
        """End every fault now and forget the scheduled ones."""
        ...
