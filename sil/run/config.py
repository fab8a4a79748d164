"""What a run is: its options, the nodes' set-up from the scenario (the plant's
configuration, the ECU's parameters), the lockstep rules for the node processes and their
command lines."""

from __future__ import annotations

import math
import shutil
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ecu.params import EcuParams, preset
from plant.aerothermal import AeroThermalPlant
from plant.fast_plant import FastPlant
from plant.faults import Fault, FaultKind
from plant.interface import Ambient, Battery, Plant, PlantConfig
from plant.sensors import SpeedPickupConfig, ThermocoupleConfig
from protocol.bus import BusSpec, BusSpecError, default_spec, parse_spec, unique_udp_spec
from sil.run.run_record import Overrides
from sil.scenario import HEALTH, PlantSettings, Scenario

NODE_GUARD_S = 2.0  # lockstep with bus faults: silence after which a node runs on its own clock


# lockstep without bus faults: a node waits for its peer as long as the run lets it (the run's
# TurnWatch tells a slow peer from a dead one, and tells the node when its peer is dead)
LOCKSTEP_GUARD_S = 3600.0


BRIDGED_GUARD_S = 0.25  # lockstep through the fault bridge: a lost frame costs this much wall time


@dataclass
class RunOptions:
    scenario: Scenario
    out_dir: Path
    mode: str = "lockstep"
    bus: str | None = None
    seed: int | None = None
    log_formats: tuple[str, ...] = ()
    plots: bool = True
    progress: bool = True
    commission: Path | None = None  # `sil identify --export` file for the ECU
    ecu_impl: str = "python"  # ECU tick: the Python firmware, its C port ("c", ecu/port) or
    # the C firmware image on QEMU ("pil", ecu/port/pil.py; on a bus only)
    pil_link: str = "eth"  # the image's CAN link (ecu.port.build.PIL_LINKS: eth or slcan)
    ecu_extra_args: tuple[str, ...] = ()  # appended to `sil ecu` (e.g. --serial pty)
    ecu_bus: str | None = None  # the ECU's side of the fault bridge (default: a second udp bus)
    compiled_loop: bool = (
        True  # inproc with the C ECU: one compiled loop (sil/run/compiled_loop.py)
    )
    overrides: Overrides = field(default_factory=Overrides)  # --controller, --param, ...
    command_line: tuple[str, ...] = ()  # the command that asked for the run, for run.json


def check_ecu_impl(opts: RunOptions) -> None:
    """What the run's ECU implementation needs, found or built before the run folder is
    touched: the C port's library for ``c``, the emulator and the firmware image for ``pil``;
    else a ValueError naming what is missing."""
    from ecu.port.build import PortBuildError, arm_pil_image
    from ecu.port.core import PortError, library
    from ecu.port.qemu import QEMU, QEMU_NOT_FOUND

    where = f"--ecu-impl {opts.ecu_impl}"
    try:
        if opts.ecu_impl == "c":
            library()
        elif opts.ecu_impl == "pil":
            if not shutil.which(QEMU):
                raise ValueError(f"{where}: the emulator {QEMU_NOT_FOUND}")
            arm_pil_image(opts.pil_link)
    except (PortBuildError, PortError) as exc:
        raise ValueError(f"{where}: {exc}") from None


def plant_config(s: Scenario, seed: int, *, nominal: bool = False) -> PlantConfig:
    """The scenario's plant; ``nominal``: the engine the ECU is commissioned for, without the
    engine-to-engine variation and at the eq. 2.32 trim whatever the scenario starts from."""
    p = s.plant
    config = PlantConfig(
        ecu_period_s=1.0 / s.ecu_rate_hz,
        ambient=Ambient(p.ambient_temperature_K, p.ambient_pressure_Pa, p.flight_speed_m_s),
        battery=Battery(p.supply_voltage_V),
        seed=seed,
    )
    if nominal:
        return config
    config = replace(
        config, initial_speed_pct=p.initial_speed_pct, initial_egt_max_k=p.initial_egt_max_K
    )
    if p.standstill:
        config = replace(config, standstill=True)
    if not p.varied:
        return config
    return replace(
        config,
        **{k: getattr(p, k) for k in HEALTH},
        pump_gain=p.pump_gain,
        faults=(Fault(0.0, FaultKind.PUMP_WEAR, p.pump_wear_per_s),) if p.pump_wear_per_s else (),
        speed_pickup=SpeedPickupConfig(noise_rpm=p.speed_noise_rpm, bias_rpm=p.speed_bias_rpm),
        thermocouple=ThermocoupleConfig(noise_k=p.egt_noise_K, bias_k=p.egt_bias_K),
    )


def build_plant(s: Scenario, seed: int, *, nominal: bool = False) -> Plant:
    config = plant_config(s, seed, nominal=nominal)
    return AeroThermalPlant(config) if s.plant.model == "aero" else FastPlant(config)


def ecu_trim_voltage(s: Scenario, plant: Plant) -> float:
    """The ECU's trim voltage: the nominal engine's at its trim (the ECU is not told how its
    engine varies, nor where the scenario starts it)."""
    if not s.plant.varied and s.plant.initial_speed_pct is None and not s.plant.standstill:
        return plant.trim_pump_voltage
    return build_plant(s, 0, nominal=True).trim_pump_voltage


def ecu_overrides(s: Scenario, trim_v: float, entry_v: float) -> dict[str, object]:
    """The scenario's ECU parameters over its preset's; ``entry_v``: the pump voltage holding the
    plant's initial state, which the ECU takes over (as if it had held it before the run)."""
    overrides: dict[str, object] = {
        "controller": s.controller.kind,
        "rate_hz": int(round(s.ecu_rate_hz)),
        "trim_v": trim_v,
        "entry_v": entry_v,
    }
    if s.controller.reading is not None:
        overrides["reading"] = s.controller.reading
    overrides.update(s.controller.params)
    return overrides


def ecu_params(s: Scenario, plant: Plant) -> EcuParams:
    """The ECU's parameters for a run of scenario s on this plant."""
    trim_v = ecu_trim_voltage(s, plant)
    params = preset(s.controller.preset or "default", **ecu_overrides(s, trim_v, trim_v))
    # the plant may hold its start beyond the ECU's range (a weak pump at maximum speed): the ECU
    # takes over at the nearest voltage it may command
    return replace(params, entry_v=min(max(plant.trim_pump_voltage, params.v_min), params.v_max))


def bus_spec(opts: RunOptions) -> BusSpec:
    if opts.bus:
        return parse_spec(opts.bus)
    spec, why = default_spec()
    print(why, file=sys.stderr)
    return spec


def strict(opts: RunOptions, s: Scenario) -> bool:
    """A lockstep run without bus faults: one sequence of frames, each node waiting for its
    peer as long as the run lets it (no node runs on its own clock)."""
    return opts.mode == "lockstep" and not s.bus_faults


def guard_s(opts: RunOptions, s: Scenario) -> float:
    if strict(opts, s):
        return LOCKSTEP_GUARD_S
    return BRIDGED_GUARD_S if s.bus_faults and opts.mode == "lockstep" else NODE_GUARD_S


def foreign_frames(opts: RunOptions, s: Scenario) -> str:
    """The nodes' --foreign-frames: the run's sequence in lockstep without bus faults, else
    only their own IDs (protocol.run_sequence)."""
    return "sequence" if strict(opts, s) else "ids"


def plant_args(
    opts: RunOptions, s: Scenario, seed: int, spec: BusSpec, tag: int, ticks: int
) -> list[str]:
    p = s.plant
    args = [
        "plant",
        "--bus",
        str(spec),
        "--run-tag",
        str(tag),
        "--model",
        p.model,
        "--rate-hz",
        str(int(round(s.ecu_rate_hz))),
        "--ticks",
        str(ticks + 1),
        "--t0",
        repr(p.ambient_temperature_K),
        "--p0",
        repr(p.ambient_pressure_Pa),
        "--flight-speed",
        repr(p.flight_speed_m_s),
        "--battery-v",
        repr(p.supply_voltage_V),
        "--seed",
        str(seed),
        "--guard-s",
        str(guard_s(opts, s)),
        "--foreign-frames",
        foreign_frames(opts, s),
        "--ready-file",
        str(ready_file(opts.out_dir, "plant")),
        "--start-file",
        str(start_file(opts.out_dir)),
        "--stats-file",
        str(stats_file(opts.out_dir, "plant")),
    ]
    if p.initial_speed_pct is not None:
        args += ["--initial-speed", repr(p.initial_speed_pct)]
        if math.isfinite(p.initial_egt_max_K):
            args += ["--initial-egt-max", repr(p.initial_egt_max_K)]
    if p.standstill:
        args.append("--standstill")
    if p.varied:
        args += _variation_args(p)
    if opts.mode == "realtime":
        args.append("--realtime")
    return args


def _variation_args(p: PlantSettings) -> list[str]:
    """``sil plant``'s options for the engine's variation from the nominal one (as
    :func:`plant_config` builds it in process)."""
    nominal = PlantSettings()
    args = []
    for name, option in (
        *((k, k) for k in HEALTH),
        ("pump_gain", "pump_gain"),
        ("speed_noise_rpm", "speed_noise_rpm"),
        ("speed_bias_rpm", "speed_bias_rpm"),
        ("egt_noise_K", "egt_noise_k"),
        ("egt_bias_K", "egt_bias_k"),
    ):
        value = getattr(p, name)
        if value != getattr(nominal, name):
            args += [f"--{option.replace('_', '-')}", repr(value)]
    if p.pump_wear_per_s:
        args += ["--fault", f"0:{FaultKind.PUMP_WEAR.value}:{p.pump_wear_per_s!r}"]
    return args


def ecu_args(
    opts: RunOptions, s: Scenario, params: EcuParams, ecu_spec: BusSpec, tag: int
) -> list[str]:
    args = [
        "ecu",
        "--bus",
        str(ecu_spec),
        "--run-tag",
        str(tag),
        "--mode",
        opts.mode,
        "--preset",
        s.controller.preset or "default",
        "--ready-file",
        str(ready_file(opts.out_dir, "ecu")),
        "--start-file",
        str(start_file(opts.out_dir)),
        "--guard",
        str(guard_s(opts, s)),
        "--foreign-frames",
        foreign_frames(opts, s),
        "--json",
        "--impl",
        opts.ecu_impl,
        *(("--pil-link", opts.pil_link) if opts.ecu_impl == "pil" else ()),
        "--stats-file",
        str(stats_file(opts.out_dir, "ecu")),
    ]
    if opts.commission is not None:
        args += ["--commission", str(opts.commission)]
    for name, value in ecu_overrides(s, params.trim_v, params.entry_v).items():
        if name == "controller":
            args += ["--controller", str(value)]
        elif name == "rate_hz":
            args += ["--rate", str(value)]
        elif name == "reading":
            args += ["--reading", str(value)]
        else:
            args += ["--param", f"{name}={value!r}"]
    return args + list(opts.ecu_extra_args)


def ecu_side(opts: RunOptions, spec: BusSpec) -> BusSpec:
    """The ECU's bus behind the fault bridge: ``--ecu-bus``, else a second loopback bus."""
    if opts.ecu_bus:
        ecu_spec = parse_spec(opts.ecu_bus)
    elif spec.interface == "udp":
        ecu_spec = unique_udp_spec()
    else:
        raise BusSpecError(
            f"bus faults on {spec} need a second bus for the ECU behind the fault bridge: "
            "give it with --ecu-bus (for example socketcan:vcan1)"
        )
    if ecu_spec == spec:
        raise BusSpecError(f"--ecu-bus {ecu_spec} is the run's bus: the bridge needs two buses")
    return ecu_spec


def demand_warnings(s: Scenario, commands: np.ndarray, params: EcuParams) -> list[str]:
    """What the ECU will not fly as asked: speed demands outside its idle..maximum range, which
    it holds at the nearer end."""
    out = []
    top, bottom = float(np.max(commands)), float(np.min(commands))
    if top > params.demand_max_pct + 1e-9:
        out.append(
            f"{s.name}: command: demand reaches {top:g} %N, over the ECU's demand_max_pct "
            f"{params.demand_max_pct:g}: the ECU holds it there"
        )
    if bottom < params.idle_pct - 1e-9:
        out.append(
            f"{s.name}: command: demand falls to {bottom:g} %N, under the ECU's idle_pct "
            f"{params.idle_pct:g}: the ECU holds it there"
        )
    return out


def ready_file(out_dir: Path, node: str) -> Path:
    """Where a node process says it is ready (``--ready-file``)."""
    return out_dir / f".{node}-ready"


def start_file(out_dir: Path) -> Path:
    """The nodes' go (``--start-file``), naming the run's senders: the plant sends tick 0
    once it exists."""
    return out_dir / ".plant-start"


def handshake_files(out_dir: Path) -> tuple[Path, ...]:
    """The node processes' ready files, the plant's start file and their stats files."""
    nodes = ("ecu", "plant")
    return (
        *(ready_file(out_dir, n) for n in nodes),
        start_file(out_dir),
        *(stats_file(out_dir, n) for n in nodes),
    )


def stats_file(out_dir: Path, node: str) -> Path:
    """Where a node process leaves its run summary (taken into summary.json, then removed)."""
    return out_dir / f".{node}-stats.json"
