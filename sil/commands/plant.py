"""`sil plant --bus SPEC ...`: the plant as a CAN node (lockstep by default)."""

from __future__ import annotations

import argparse
import gc
import math
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from protocol import strict_json
from sil.run.membership import say_ready, wait_to_start
from sil.run.node_options import add_launcher_options, run_sequence
from sil.run.parent_death import NodeStop, PeerLost
from sil.validation import bus_option, option

NAME = "plant"
HELP = "run the simulated engine (aero-thermal or fast model) as a CAN node"
# the engine as built and its sensors (sil.scenario's [plant] variation): option, range, default
VARIATION = (
    ("compressor_efficiency", 0.1, 1.5, 1.0),
    ("compressor_flow", 0.1, 1.5, 1.0),
    ("turbine_efficiency", 0.1, 1.5, 1.0),
    ("turbine_flow", 0.1, 1.5, 1.0),
    ("pump_gain", 0.1, 2.0, 1.0),
    ("speed_noise_rpm", 0.0, 10_000.0, 20.0),
    ("speed_bias_rpm", -10_000.0, 10_000.0, 0.0),
    ("egt_noise_k", 0.0, 100.0, 1.0),
    ("egt_bias_k", -200.0, 200.0, 0.0),
)


def fault_kinds() -> tuple[str, ...]:
    """The fault kinds ``--fault`` takes: the scenario files' fault names (the DBC's FaultTarget,
    CLEAR_ALL aside) and the plant's own (PUMP_DRY, PUMP_STALL)."""
    from plant.faults import FaultKind

    return tuple(kind.value.upper() for kind in FaultKind)


def _fault(text: str):  # noqa: ANN202 - argparse type
    """AT_S:KIND[:VALUE[:DURATION_S]], e.g. 30:PUMP_EFFECTIVENESS:0.5 (the document's failure);
    KIND in any case."""
    from plant.faults import Fault, FaultKind

    parts = text.split(":")
    if not 2 <= len(parts) <= 4:
        raise argparse.ArgumentTypeError(f"fault {text!r}: expected AT_S:KIND[:VALUE[:DURATION_S]]")
    name = parts[1].strip().upper()
    if name not in fault_kinds():
        raise argparse.ArgumentTypeError(
            f"fault {text!r}: unknown kind {parts[1]!r} (kinds: {', '.join(fault_kinds())})"
        )
    try:
        at = float(parts[0])
        value = float(parts[2]) if len(parts) > 2 and parts[2] != "" else None
        duration = float(parts[3]) if len(parts) > 3 else None
        return Fault(at, FaultKind(name.lower()), value, duration)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"fault {text!r}: {exc}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bus",
        type=bus_option,
        metavar="SPEC",
        help="bus spec (default: vcan0 if up, else a "
        "loopback multicast bus of this run's own; see protocol.bus)",
    )
    parser.add_argument(
        "--model",
        choices=("aero", "fast"),
        default="aero",
        help="aero-thermal engine (ch. 2) or the fast model of eq. 3.24",
    )
    parser.add_argument(
        "--rate-hz", type=option(integer=True, ecu_rate_hz=True), default=100,
        help="ECU rate (default 100 Hz; a divisor of the plant's 1 kHz)",
    )  # fmt: skip
    parser.add_argument(
        "--ticks", type=option(integer=True, positive=True), default=None,
        help="stop after this many ECU periods",
    )  # fmt: skip
    parser.add_argument(
        "--realtime", action="store_true", help="pace by the wall clock instead of lockstep"
    )
    parser.add_argument(
        "--guard-s",
        type=option(positive=True, hi=3600.0),
        default=1.0,
        help="lockstep: wall-clock wait for the ECU before holding its command",
    )
    parser.add_argument(
        "--watchdog-ticks",
        type=option(integer=True, positive=True),
        default=10,
        help="ticks without an actuator frame before pump power is removed",
    )
    parser.add_argument(
        "--fuel",
        type=option(positive=True, hi=0.1),
        default=0.008,
        help="start at the steady state of this fuel flow, kg/s",
    )
    parser.add_argument(
        "--initial-speed",
        type=option(lo=10.0, hi=120.0),
        metavar="PCT",
        help="start instead at the steady state holding this speed, %%N",
    )
    parser.add_argument(
        "--initial-egt-max",
        type=option(lo=300.0, hi=2500.0),
        default=math.inf,
        metavar="K",
        help="with --initial-speed: the fastest steady state within this EGT if that is hotter",
    )
    parser.add_argument(
        "--standstill",
        action="store_true",
        help="start at rest, cold and unlit (aero plant): the ECU's sequencer starts it",
    )
    # the ranges a scenario file's [plant] takes (sil/scenario)
    parser.add_argument(
        "--t0", type=option(lo=200, hi=350), default=288.15, help="ambient temperature, K"
    )
    parser.add_argument(
        "--p0", type=option(lo=20_000, hi=110_000), default=101325.0, help="ambient pressure, Pa"
    )
    parser.add_argument(
        "--flight-speed", type=option(lo=0, hi=300), default=0.0, help="flight speed, m/s"
    )
    parser.add_argument(
        "--battery-v", type=option(lo=1, hi=60), default=22.2, help="battery voltage, V"
    )
    parser.add_argument("--seed", type=int, default=0, help="sensor noise seed")
    parser.add_argument(
        "--ready-file",
        type=Path,
        metavar="PATH",
        help="create this file once the node is built and listens on the bus (with "
        "--start-file: when it waits for it)",
    )
    parser.add_argument(
        "--start-file",
        type=Path,
        metavar="PATH",
        help="get ready and join the bus, then wait until this file exists before sending tick 0 "
        "(frames heard meanwhile are kept; a launcher starts the plant and the ECU at once and "
        "creates it when both are ready)",
    )
    for name, lo, hi, default in VARIATION:
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            type=option(lo=lo, hi=hi),
            default=default,
            metavar="X",
            help=f"engine variation: {name} ({lo:g}..{hi:g}, default {default:g})",
        )
    add_launcher_options(parser)
    parser.add_argument(
        "--fault",
        type=_fault,
        action="append",
        default=[],
        metavar="AT_S:KIND[:VALUE[:DURATION_S]]",
        help="scheduled fault, repeatable; KIND (in any case) one of the scenario files' fault "
        f"names or the plant's own: {', '.join(fault_kinds())}",
    )


def _skip_blas_probe() -> None:
    """On its first compile numba looks for a BLAS by importing scipy.linalg (0.4 s of every
    plant start). The plant's compiled code calls no BLAS and nothing else in this process
    imports scipy, so the probe is told there is none (an entry of None makes the import fail)."""
    sys.modules.setdefault("scipy.linalg.cython_blas", None)  # type: ignore[arg-type]


@contextmanager
def _without_collection() -> Iterator[None]:
    """No collector passes while the node is built (numba's import and cache make objects by the
    hundred thousand: 0.2-0.3 s of passes in a plant's start); what was built is then frozen, so
    that no later pass goes over it, and the collector is as it was."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def build_node(args: argparse.Namespace):  # noqa: ANN201
    from plant.aerothermal import AeroThermalPlant
    from plant.fast_plant import FastPlant
    from plant.interface import Ambient, Battery, PlantConfig
    from plant.node import PlantNode
    from plant.sensors import SpeedPickupConfig, ThermocoupleConfig

    config = PlantConfig(
        ecu_period_s=1.0 / args.rate_hz,
        ambient=Ambient(args.t0, args.p0, args.flight_speed),
        battery=Battery(args.battery_v),
        initial_fuel_kg_s=args.fuel,
        initial_speed_pct=args.initial_speed,
        initial_egt_max_k=args.initial_egt_max,
        standstill=args.standstill,
        faults=tuple(args.fault),
        seed=args.seed,
        compressor_efficiency=args.compressor_efficiency,
        compressor_flow=args.compressor_flow,
        turbine_efficiency=args.turbine_efficiency,
        turbine_flow=args.turbine_flow,
        pump_gain=args.pump_gain,
        speed_pickup=SpeedPickupConfig(
            noise_rpm=args.speed_noise_rpm, bias_rpm=args.speed_bias_rpm
        ),
        thermocouple=ThermocoupleConfig(noise_k=args.egt_noise_k, bias_k=args.egt_bias_k),
    )
    plant = AeroThermalPlant(config) if args.model == "aero" else FastPlant(config)
    return PlantNode(
        plant, lockstep=not args.realtime, max_ticks=args.ticks, watchdog_ticks=args.watchdog_ticks
    )


def run(args: argparse.Namespace) -> int:
    from protocol.bus import BusSpecError, default_spec, open_bus, parse_spec
    from protocol.node import listen_for, realtime_scheduling, run_lockstep, run_realtime
    from protocol.run_bus import RunBus

    _skip_blas_probe()
    try:
        with _without_collection():
            node = build_node(args)
    except ValueError as exc:
        print(f"sil plant: error: {exc}", file=sys.stderr)
        return 2
    if args.bus is None:
        spec, why = default_spec()
        print(why, file=sys.stderr)
    else:
        try:
            spec = parse_spec(args.bus)
        except BusSpecError as exc:
            print(f"sil plant: error: {exc}", file=sys.stderr)
            return 2
    stop = NodeStop()  # SIGTERM (or the run's end) ends the run cleanly, with the summary
    try:
        sequence = run_sequence(args, None, "Plant", args.rate_hz)
        bus = RunBus(open_bus(spec), args.run_tag, sequence)
    except (BusSpecError, ValueError) as exc:
        print(f"sil plant: error: {exc}", file=sys.stderr)
        return 2
    # on the bus, with its filters, before it says it is ready: the frames sent before tick 0
    # (the FaultInjects and Demands due at tick 0) wait in its queue until it starts
    listen_for(node, bus)
    lost = PeerLost(on_lost=bus.relax)
    if args.ready_file is not None:
        say_ready(args.ready_file, bus)
    if args.start_file is not None:  # (the run's senders, named there, the only ones heard)
        wait_to_start(args.start_file, bus, stop.is_set)
    try:
        if args.realtime:
            policy = realtime_scheduling()
            stats = run_realtime(node, bus, node.plant.config.ecu_period_s, should_stop=stop.is_set)
            stats.scheduling = policy
        else:
            guard = lost.guard(args.guard_s)
            stats = run_lockstep(node, bus, guard_s=guard, should_stop=stop.is_set)
    except KeyboardInterrupt:
        return 130
    finally:
        bus.shutdown()
    o = node.plant.outputs
    print(
        f"plant: {node.tick} ticks, {o.time_s:.2f} s simulated, N = {o.n_pct:.2f} %, "
        f"EGT = {o.egt_true_k:.0f} K; watchdog trips {node.watchdog_trips}, actuator frames "
        f"rejected {node.actuator_rejected}, faults applied {node.faults_applied} / rejected "
        f"{node.faults_rejected}; frames received {stats.received}"
    )
    if args.stats_file is not None:
        summary = {
            "ticks": node.tick,
            "watchdog_trips": node.watchdog_trips,
            "actuator_rejected": node.actuator_rejected,
            **stats.summary(),
            **bus.stats(),
        }
        args.stats_file.write_text(strict_json.dumps(summary, indent=2) + "\n")
    return 0
