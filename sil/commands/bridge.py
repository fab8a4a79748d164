"""`sil bridge FAULTS --bus SPEC --ecu-bus SPEC`: the bus fault injector between two buses.

Put it in front of a real ECU on an adapter (``--ecu-bus socketcan:can0``) or any node: every
frame heard on one bus goes out on the other through the injector, with the faults of FAULTS
(``[[bus_fault]]`` tables as in a scenario, plus optional ``ecu_rate_hz`` and ``seed``). Fault
windows count ECU periods from the bridge's start by the wall clock, or with ``--lockstep`` from
the plant's PlantSensors ticks. Each fault applied is logged; the log is written at the end, also
on Ctrl-C.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from contextlib import ExitStack
from pathlib import Path

from protocol import strict_json
from protocol.bus import BusSpecError, open_bus, parse_spec
from protocol.codec import Codec
from sil import scenario, validation

NAME = "bridge"
HELP = "put the bus fault injector between two buses (in front of a real ECU, for example)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("faults", type=Path, help="TOML file with [[bus_fault]] tables")
    parser.add_argument(
        "--bus", type=validation.bus_option, required=True, metavar="SPEC", help="the plant's side"
    )
    parser.add_argument(
        "--ecu-bus",
        type=validation.bus_option,
        required=True,
        metavar="SPEC",
        help="the ECU's side",
    )
    parser.add_argument(
        "--lockstep",
        action="store_true",
        help="count ticks by the plant's PlantSensors frames instead of the wall clock",
    )
    parser.add_argument("--seed", type=int, help="injector seed (default: the file's)")
    parser.add_argument(
        "--duration",
        type=validation.option(positive=True),
        metavar="S",
        help="stop after S seconds",
    )
    parser.add_argument(
        "--events",
        type=validation.file_option,
        metavar="FILE",
        help="write the fault log (JSON; checked before the bridge starts)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def _stop_on_sigterm() -> None:
    def stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)


def run(args: argparse.Namespace) -> int:
    from sil.busfault.bridge import Bridge, SensorTicks, WallTicks
    from sil.busfault.injector import Injector

    try:
        spec = scenario.load_bridge_faults(args.faults)
        bus, ecu_bus = parse_spec(args.bus), parse_spec(args.ecu_bus)
    except (scenario.ScenarioError, BusSpecError) as exc:
        print(f"sil bridge: {exc}", file=sys.stderr)
        return 2
    if bus == ecu_bus:
        print(f"sil bridge: --bus and --ecu-bus are the same bus ({bus})", file=sys.stderr)
        return 2
    seed = spec.seed if args.seed is None else args.seed
    injector = Injector(spec.faults, spec.ecu_rate_hz, seed, Codec())
    ticks = SensorTicks() if args.lockstep else WallTicks(spec.ecu_rate_hz)
    _stop_on_sigterm()
    status = "stopped"
    t0 = time.monotonic()
    try:
        with ExitStack() as stack:
            a = stack.enter_context(open_bus(bus))
            b = stack.enter_context(open_bus(ecu_bus))
            bridge = stack.enter_context(Bridge(a, b, injector, ticks=ticks))
            print(f"sil bridge: {bus} <-> {ecu_bus}, {len(spec.faults)} faults", file=sys.stderr)
            try:
                while args.duration is None or time.monotonic() - t0 < args.duration:
                    time.sleep(0.1)
            except KeyboardInterrupt:
                status = "interrupted"
    except BusSpecError as exc:
        print(f"sil bridge: {exc}", file=sys.stderr)
        return 2
    summary = {
        "status": status,
        "bus": str(bus),
        "ecu_bus": str(ecu_bus),
        "seed": seed,
        "wall_time_s": time.monotonic() - t0,
        "last_tick": ticks.now(),
        "forwarded_to_plant_side": bridge.forwarded[0],
        "forwarded_to_ecu_side": bridge.forwarded[1],
        "send_errors": bridge.errors,
        "events": len(injector.events),
    }
    if args.events is not None:
        try:
            args.events.write_text(strict_json.dumps(injector.events, indent=1) + "\n")
        except OSError as exc:
            print(f"sil bridge: --events: cannot write {args.events}: {exc}", file=sys.stderr)
            return 2
    if args.json:
        print(strict_json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            print(f"{key:<24} {value}")
    return 0
