"""Scenario files (TOML): plant, controller, command profile, faults, duration, ECU rate, seed.

A file is checked completely before anything starts; the first problem is reported as
``FILE: field 'command.component[2].frequency_hz': expected a positive number, got -1``.
Shipped scenarios live in ``sil/scenario/library/`` and are found by name.

    name = "thesis-5.3-mrac-aero"
    description = "..."
    duration_s = 300
    ecu_rate_hz = 100          # 50..1000
    seed = 1

    [plant]
    model = "aero"             # aero | fast
    ambient_temperature_K = 288.15
    ambient_pressure_Pa = 101325
    flight_speed_m_s = 0
    supply_voltage_V = 22.2     # pump battery (6S LiPo)

    [controller]
    kind = "mrac"              # mrac | pid | open_loop
    preset = "sec5_3_mrac_aero"  # an ECU parameter preset (ecu.params.PRESETS; optional)
    reading = "printed"        # printed | reproducing: how the document's gains are read
                               # (ecu.params.READINGS; optional, default the preset's)
    params = { }               # overrides of ECU parameters by name (optional; a table such as
                               # accel_line_v or a pair such as init_kx as a list of numbers)

    [command]                  # %N for mrac/pid, volts for open_loop
    base = "trim"              # a number, or "trim": 89.68 %N, or the trim pump voltage
    [[command.component]]
    kind = "square"            # step | staircase | square | sine | ramp | csv
    amplitude = 1.0
    frequency_hz = 0.05

    [[fault]]
    time_s = 30
    target = "PUMP_EFFECTIVENESS"   # a FaultTarget of the DBC
    value = 0.5

    [[bus_fault]]              # faults between the nodes (sil.busfault.spec; inproc mode)
    kind = "drop"
    ids = ["PlantSensors"]
    start_s = 20
    duration_s = 0.5

Engine-to-engine variation, as built (all optional, nominal by default; ``sil run --mode inproc``):

    [plant]
    compressor_efficiency = 1.0  # health scalars of the maps (aero plant), 0.1..1.5
    compressor_flow = 1.0
    turbine_efficiency = 1.0
    turbine_flow = 1.0
    pump_gain = 1.0            # delivered / table fuel flow, 0.1..2.0
    pump_wear_per_s = 0.0      # pump effectiveness lost per second from the start
    speed_noise_rpm = 20       # speed pickup noise (1 sigma) and offset
    speed_bias_rpm = 0
    egt_noise_K = 1            # thermocouple noise (1 sigma) and offset
    egt_bias_K = 0

Starting point (default: the steady state of eq. 2.32's 8 g/s, whatever speed that gives):

    [plant]
    initial_speed_pct = 90     # the steady state holding this speed, each engine its own fuel
    initial_egt_max_K = 1280   # or the fastest steady state within this EGT, if that is hotter
    standstill = true          # or at rest, cold and unlit: the ECU's sequencer starts it (aero)

and the end of the run (default: armed throughout):

    [command]
    stop_s = 60                # the arm request released and a stop requested from this time:
                               # the ECU shuts the engine down and cools it
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from functools import lru_cache
from pathlib import Path
from typing import Any

from ecu import faults as ecu_faults
from ecu import modes as ecu_modes
from ecu.params import CONTROLLERS, PRESETS, READINGS, EcuParams
from plant.faults import CLEAR_ALL, ENGINE_FAULTS, FAULT_TARGETS, target_value_range
from protocol.dbc import load_database
from sil import validation
from sil.busfault.spec import KINDS, RATED, BusFault, Expectation
from sil.scenario import profiles

SCENARIO_DIR = Path(__file__).with_name("library")
PLANT_MODELS = ("aero", "fast")


class ScenarioError(validation.InputError):
    """A scenario file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class PlantSettings:
    model: str = "aero"
    ambient_temperature_K: float = 288.15
    ambient_pressure_Pa: float = 101325.0
    flight_speed_m_s: float = 0.0
    supply_voltage_V: float = 22.2
    compressor_efficiency: float = 1.0
    compressor_flow: float = 1.0
    turbine_efficiency: float = 1.0
    turbine_flow: float = 1.0
    pump_gain: float = 1.0
    pump_wear_per_s: float = 0.0
    speed_noise_rpm: float = 20.0
    speed_bias_rpm: float = 0.0
    egt_noise_K: float = 1.0
    egt_bias_K: float = 0.0
    initial_speed_pct: float | None = None
    initial_egt_max_K: float = math.inf
    standstill: bool = False  # at rest, cold and unlit: the ECU starts the engine

    @property
    def varied(self) -> bool:
        """True when the engine differs from the nominal one in anything but ambient and supply."""
        nominal = PlantSettings(
            self.model,
            self.ambient_temperature_K,
            self.ambient_pressure_Pa,
            self.flight_speed_m_s,
            self.supply_voltage_V,
            initial_speed_pct=self.initial_speed_pct,
            initial_egt_max_K=self.initial_egt_max_K,
            standstill=self.standstill,
        )
        return self != nominal


HEALTH = ("compressor_efficiency", "compressor_flow", "turbine_efficiency", "turbine_flow")


@dataclass(frozen=True)
class ControllerSettings:
    kind: str = "mrac"
    preset: str | None = None
    params: dict[str, float | tuple[float, ...]] = field(default_factory=dict)
    reading: str | None = None  # ecu.params.READINGS; None: the preset's


@dataclass(frozen=True)
class Fault:
    time_s: float
    target: str
    value: float


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    path: Path | None
    duration_s: float
    ecu_rate_hz: float
    seed: int
    plant: PlantSettings
    controller: ControllerSettings
    command_base: float | str  # a number or "trim"
    command_components: tuple[profiles.Component, ...]
    faults: tuple[Fault, ...]
    bus_faults: tuple[BusFault, ...] = ()
    stop_s: float | None = None  # from then on the arm request is released and a stop requested

    @property
    def stop_tick(self) -> int | None:
        """The first tick of the stop request (None: armed throughout)."""
        return None if self.stop_s is None else round(self.stop_s * self.ecu_rate_hz)

    def profile(self, trim_value: float) -> profiles.Profile:
        """The command profile, with ``trim_value`` standing for a base of "trim"."""
        base = trim_value if self.command_base == "trim" else float(self.command_base)
        return profiles.Profile(base, self.command_components)

    @property
    def ticks(self) -> int:
        return int(round(self.duration_s * self.ecu_rate_hz))


@lru_cache(maxsize=1)
def fault_targets() -> tuple[str, ...]:
    """Fault names, from the FaultTarget value table of the DBC."""
    return tuple(_fault_codes())


@lru_cache(maxsize=1)
def _fault_codes() -> dict[str, int]:
    """Fault name -> its FaultTarget value, from the DBC."""
    message = load_database().get_message_by_name("FaultInject")
    choices = message.get_signal_by_name("FaultTarget").choices or {}
    return {str(choices[k]): int(k) for k in sorted(choices)}


@lru_cache(maxsize=1)
def fault_value_field() -> tuple[float, float]:
    """The range of the FaultInject frame's FaultValue signal (DBC)."""
    signal = load_database().get_message_by_name("FaultInject").get_signal_by_name("FaultValue")
    return float(signal.minimum), float(signal.maximum)


def fault_value_range(target: str) -> tuple[float, float, str]:
    """The values a fault of ``target`` may take: what the FaultInject frame carries (the DBC)
    within what the plant applies for it (plant.faults); and a phrase saying whose limit."""
    lo, hi = fault_value_field()
    plant = target_value_range(_fault_codes()[target])
    if plant is None:
        return lo, hi, "the range of the FaultInject frame's FaultValue"
    return max(lo, plant[0]), min(hi, plant[1]), "the values the plant applies"


def _fault(r: _Reader, duration: float, model: str) -> Fault:
    """A ``[[fault]]`` table, its value checked against the frame and the plant."""
    time_s = r.number("time_s", lo=0)
    if time_s > duration:
        raise r.fail("time_s", f"a time within the run (0..{duration:g} s)", time_s)
    target = r.text("target", choices=fault_targets())
    code = _fault_codes()[target]
    if model == "fast" and code != CLEAR_ALL and FAULT_TARGETS[code] in ENGINE_FAULTS:
        raise r.fail(
            "target",
            "a fault the fast plant has (it has no compressor, turbine, ambient, starter, "
            "igniter or fuel supply model)",
            target,
        )
    lo, hi, why = fault_value_range(target)
    value = r.number("value", 0.0 if lo <= 0.0 <= hi else ...)
    if not lo <= value <= hi:
        raise r.fail("value", f"a number in {lo:.10g}..{hi:.10g} for {target} ({why})", value)
    r.done()
    return Fault(time_s, target, value)


class _Reader:
    """Typed access to a TOML table that names the file and the field in every error."""

    def __init__(self, source: str, table: dict[str, Any], prefix: str = "") -> None:
        self.source, self.table, self.prefix = source, table, prefix
        self.used: set[str] = set()

    def fail(self, key: str, expected: str, got: Any) -> ScenarioError:
        return ScenarioError(
            f"{self.source}: field '{self.prefix}{key}': expected {expected}, got {got!r}"
        )

    def get(self, key: str, default: Any = ..., *, missing: str = "a value") -> Any:
        self.used.add(key)
        if key not in self.table:
            if default is ...:
                raise ScenarioError(
                    f"{self.source}: field '{self.prefix}{key}' is missing (expected {missing})"
                )
            return default
        return self.table[key]

    def number(
        self,
        key: str,
        default: Any = ...,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> float:
        value = self.get(key, default, missing="a number")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(key, "a number", value)
        if not math.isfinite(value):
            raise self.fail(key, "a finite number", value)
        if positive and value <= 0:
            raise self.fail(key, "a positive number", value)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.fail(key, validation.within(lo, hi), value)
        return float(value)

    def numbers(self, key: str, length: int) -> tuple[float, ...]:
        value = self.get(key, missing=f"a list of {length} numbers")
        if (
            not isinstance(value, list)
            or len(value) != length
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        ):
            raise self.fail(key, f"a list of {length} numbers", value)
        if not all(math.isfinite(v) for v in value):
            raise self.fail(key, f"a list of {length} finite numbers", value)
        return tuple(float(v) for v in value)

    def text(self, key: str, default: Any = ..., *, choices: tuple[str, ...] | None = None) -> str:
        value = self.get(key, default, missing="a string")
        if not isinstance(value, str):
            raise self.fail(key, "a string", value)
        if choices is not None and value not in choices:
            raise self.fail(key, "one of " + ", ".join(choices), value)
        return value

    def sub(self, key: str, *, required: bool = False) -> _Reader:
        value = self.get(key, ... if required else {}, missing="a table")
        if not isinstance(value, dict):
            raise self.fail(key, "a table", value)
        return _Reader(self.source, value, f"{self.prefix}{key}.")

    def tables(self, key: str) -> list[_Reader]:
        value = self.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.fail(key, "a list of tables ([[...]])", value)
        return [_Reader(self.source, v, f"{self.prefix}{key}[{i}].") for i, v in enumerate(value)]

    def done(self) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            raise ScenarioError(
                f"{self.source}: unknown field '{self.prefix}{unknown[0]}' "
                f"(known here: {', '.join(sorted(self.used))})"
            )


def _component(r: _Reader, base_dir: Path) -> profiles.Component:
    kind = r.text("kind", choices=("step", "staircase", "square", "sine", "ramp", "csv"))
    if kind == "step":
        c: profiles.Component = profiles.Step(r.number("time_s", lo=0), r.number("value"))
    elif kind == "staircase":
        levels = r.get("levels", missing="a list of numbers")
        if (
            not isinstance(levels, list)
            or not levels
            or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in levels
            )
        ):
            raise r.fail("levels", "a non-empty list of finite numbers", levels)
        c = profiles.Staircase(
            tuple(float(v) for v in levels),
            r.number("step_s", positive=True),
            r.number("start_s", 0.0, lo=0),
        )
    elif kind == "square":
        c = profiles.Square(
            r.number("amplitude"),
            r.number("frequency_hz", positive=True),
            r.number("start_s", 0.0, lo=0),
        )
    elif kind == "sine":
        c = profiles.Sine(
            r.number("amplitude"),
            r.number("frequency_hz", positive=True),
            r.number("phase_deg", 0.0),
            r.number("start_s", 0.0, lo=0),
        )
    elif kind == "ramp":
        start, end = r.number("start_s", lo=0), r.number("end_s", lo=0)
        if end <= start:
            raise r.fail("end_s", f"a time after start_s ({start})", end)
        c = profiles.Ramp(start, end, r.number("value"))
    else:
        path = base_dir / r.text("path")
        if not path.is_file():
            raise r.fail("path", "an existing CSV file", str(path))
        try:
            validation.input_file(path, f"{r.source}: field '{r.prefix}path': {path}")
        except validation.InputError as exc:
            raise ScenarioError(str(exc)) from None
        try:
            c = profiles.Table.from_csv(
                path, r.text("time_column", "time_s"), r.text("value_column", "value")
            )
        except ValueError as exc:
            raise ScenarioError(f"{r.source}: field '{r.prefix}path': {exc}") from None
    r.done()
    return c


def _flag(r: _Reader, key: str) -> bool:
    value = r.get(key, False)
    if not isinstance(value, bool):
        raise r.fail(key, "true or false", value)
    return value


def _ecu_rate(r: _Reader) -> float:
    value = r.number("ecu_rate_hz", 100.0, lo=50, hi=1000)
    try:
        return validation.ecu_rate(r.source, "field 'ecu_rate_hz'", value)
    except validation.InputError as exc:
        raise ScenarioError(str(exc)) from None


def _integer(r: _Reader, key: str, default: int, lo: int, hi: int) -> int:
    value = r.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise r.fail(key, f"an integer in {lo}..{hi}", value)
    return value


@lru_cache(maxsize=1)
def _message_ids() -> dict[str, int]:
    return {m.name: m.frame_id for m in load_database().messages}


def _frame_ids(r: _Reader, key: str) -> tuple[int, ...]:
    by_name = _message_ids()
    value = r.get(key, [])
    if not isinstance(value, list):
        raise r.fail(key, "a list of message names or frame IDs", value)
    ids = []
    for item in value:
        if isinstance(item, str) and item in by_name:
            ids.append(by_name[item])
        elif isinstance(item, int) and not isinstance(item, bool) and 0 <= item <= 0x7FF:
            ids.append(item)
        else:
            names = ", ".join(by_name)
            raise r.fail(key, f"message names ({names}) or 11-bit frame IDs", item)
    return tuple(ids)


def _bus_fault(r: _Reader, duration: float) -> BusFault:
    kind = r.text("kind", choices=KINDS)
    ids = _frame_ids(r, "ids")
    if not ids and kind != "bus_off":
        raise r.fail("ids", "at least one message (only bus_off applies to every frame)", [])
    start = r.number("start_s", lo=0, hi=duration)
    length = r.number("duration_s", positive=True)
    rate = r.number("rate", 1.0, lo=0, hi=1)
    if kind not in RATED and "rate" in r.table:
        raise r.fail("rate", f"no rate for {kind} (only {', '.join(RATED)})", rate)
    detect = r.get("detect", None)
    bits = ("E2E", *ecu_faults.NAMES.values())
    if detect is not None and detect not in bits:
        raise r.fail("detect", "one of " + ", ".join(bits), detect)
    within = r.get("within_ticks", None)
    if detect is not None or within is not None:
        within = _integer(r, "within_ticks", 0, 0, 1_000_000)
    mode = r.text("fallback_mode", choices=ecu_modes.NAMES) if "fallback_mode" in r.table else None
    recover = r.get("recover_within_ticks", None)
    if recover is not None:
        recover = _integer(r, "recover_within_ticks", 0, 0, 1_000_000)
        if detect in (None, "E2E"):
            raise r.fail("recover_within_ticks", "a detect fault bit to clear", detect)
    starve = r.get("starve", False)
    if not isinstance(starve, bool):
        raise r.fail("starve", "true or false", starve)
    fault = BusFault(
        kind,
        ids,
        start,
        length,
        rate=rate,
        burst=_integer(r, "burst", 1, 1, 10_000),
        delay_ticks=_integer(r, "delay_ticks", 0, 0, 10_000),
        jitter_ticks=_integer(r, "jitter_ticks", 0, 0, 10_000),
        bits=_integer(r, "bits", 1, 1, 8),
        flood_per_tick=_integer(r, "flood_per_tick", 1, 1, 100),
        starve=starve,
        expect=Expectation(detect, within, mode, recover),
    )
    if kind == "delay" and fault.delay_ticks + fault.jitter_ticks == 0:
        raise r.fail("delay_ticks", "a delay of at least one tick", 0)
    r.done()
    return fault


def parse(text: str, source: str, base_dir: Path, path: Path | None = None) -> Scenario:
    """Check and build a scenario from TOML text; ``source`` names it in errors."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from None
    top = _Reader(source, data)
    name = top.text("name", Path(source).stem)
    description = top.text("description", "")
    duration = top.number("duration_s", positive=True, hi=86_400)
    rate = _ecu_rate(top)
    seed = top.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise top.fail("seed", "a non-negative integer", seed)

    p = top.sub("plant")
    plant = PlantSettings(
        model=p.text("model", "aero", choices=PLANT_MODELS),
        ambient_temperature_K=p.number("ambient_temperature_K", 288.15, lo=200, hi=350),
        ambient_pressure_Pa=p.number("ambient_pressure_Pa", 101325.0, lo=20_000, hi=110_000),
        flight_speed_m_s=p.number("flight_speed_m_s", 0.0, lo=0, hi=300),
        supply_voltage_V=p.number("supply_voltage_V", 22.2, lo=1, hi=60),
        **{k: p.number(k, 1.0, lo=0.1, hi=1.5) for k in HEALTH},
        pump_gain=p.number("pump_gain", 1.0, lo=0.1, hi=2.0),
        pump_wear_per_s=p.number("pump_wear_per_s", 0.0, lo=0, hi=1),
        speed_noise_rpm=p.number("speed_noise_rpm", 20.0, lo=0, hi=10_000),
        speed_bias_rpm=p.number("speed_bias_rpm", 0.0, lo=-10_000, hi=10_000),
        egt_noise_K=p.number("egt_noise_K", 1.0, lo=0, hi=100),
        egt_bias_K=p.number("egt_bias_K", 0.0, lo=-200, hi=200),
        initial_speed_pct=(
            p.number("initial_speed_pct", lo=10, hi=120) if "initial_speed_pct" in p.table else None
        ),
        initial_egt_max_K=(
            p.number("initial_egt_max_K", lo=300, hi=2500)
            if "initial_egt_max_K" in p.table
            else math.inf
        ),
        standstill=_flag(p, "standstill"),
    )
    if plant.standstill and plant.model != "aero":
        raise p.fail("standstill", "false: only the aero plant starts from rest", True)
    if plant.standstill and plant.initial_speed_pct is not None:
        raise p.fail("initial_speed_pct", "no value: the engine starts from rest", "a speed")
    if plant.model == "fast":
        for k in HEALTH:
            if getattr(plant, k) != 1.0:
                raise p.fail(
                    k, "1.0: the fast plant has no compressor or turbine", getattr(plant, k)
                )
    p.done()

    c = top.sub("controller")
    kind = c.text("kind", "mrac", choices=CONTROLLERS)
    preset = c.text("preset", choices=tuple(sorted(PRESETS))) if "preset" in c.table else None
    reading = c.text("reading", choices=READINGS) if "reading" in c.table else None
    params_reader = c.sub("params")
    known = {f.name for f in fields(EcuParams)} - {"controller", "rate_hz", "reading"}
    for key in params_reader.table:
        if key not in known:
            raise params_reader.fail(key, "an ECU parameter (ecu.params.EcuParams field)", key)
    lists = {f.name: len(f.default) for f in fields(EcuParams) if isinstance(f.default, tuple)}
    params = {
        k: params_reader.numbers(k, lists[k]) if k in lists else params_reader.number(k)
        for k in list(params_reader.table)
    }
    params_reader.done()
    c.done()

    cmd = top.sub("command", required=True)
    base = cmd.get("base", 0.0)
    if base != "trim" and (
        isinstance(base, bool) or not isinstance(base, int | float) or not math.isfinite(base)
    ):
        raise cmd.fail("base", 'a finite number or "trim"', base)
    components = tuple(_component(r, base_dir) for r in cmd.tables("component"))
    stop_s = cmd.number("stop_s", lo=0, hi=duration) if "stop_s" in cmd.table else None
    cmd.done()

    faults = [_fault(r, duration, plant.model) for r in top.tables("fault")]
    bus_faults = tuple(_bus_fault(r, duration) for r in top.tables("bus_fault"))
    top.done()
    return Scenario(
        name,
        description,
        path,
        duration,
        rate,
        int(seed),
        plant,
        ControllerSettings(kind, preset, params, reading),
        base if base == "trim" else float(base),
        components,
        tuple(sorted(faults, key=lambda f: f.time_s)),
        bus_faults,
        stop_s,
    )


@dataclass(frozen=True)
class BridgeFaults:
    """A fault file for ``sil bridge``: the ECU rate its ticks count, a seed, the faults."""

    ecu_rate_hz: float
    seed: int
    faults: tuple[BusFault, ...]


def load_bridge_faults(path: Path) -> BridgeFaults:
    """``[[bus_fault]]`` tables with an optional ``ecu_rate_hz`` (100) and ``seed`` (0), as in a
    scenario (a scenario file is read for these alone); windows may start at any time."""
    _readable(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    top = _Reader(str(path), data)
    rate = _ecu_rate(top)
    seed = top.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise top.fail("seed", "a non-negative integer", seed)
    faults = tuple(_bus_fault(r, 86_400.0) for r in top.tables("bus_fault"))
    if not faults:
        raise ScenarioError(f"{path}: no [[bus_fault]] tables")
    return BridgeFaults(rate, seed, faults)


def load(name_or_path: str | Path) -> Scenario:
    """A shipped scenario by name, or a scenario file by path."""
    path = Path(name_or_path)
    if not path.is_file():
        shipped = SCENARIO_DIR / f"{name_or_path}.toml"
        if shipped.is_file():
            path = shipped
        elif not path.exists():
            known = ", ".join(shipped_names())
            raise ScenarioError(
                f"{name_or_path}: no such file or shipped scenario (shipped: {known})"
            )
    _readable(path)  # (a device, a pipe or a folder is refused here)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    return parse(text, str(path), path.parent, path)


def _readable(path: Path) -> None:
    """Refuse a kernel file or a device as the file to read (validation.input_file)."""
    try:
        validation.input_file(path)
    except validation.InputError as exc:
        raise ScenarioError(str(exc)) from None


def shipped_names() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))
