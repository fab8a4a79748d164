"""`sil ecu --bus SPEC`: the ECU firmware as a CAN node (lockstep or real time)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ecu.params import CONTROLLERS
from protocol import strict_json
from sil.run.membership import say_ready, wait_to_start
from sil.run.node_options import add_launcher_options, add_pil_link, run_sequence, xcp_ids
from sil.run.parent_death import NodeStop, PeerLost
from sil.validation import bus_option, input_option, option

NAME = "ecu"
HELP = "run the ECU firmware as a CAN node on a bus (lockstep: one tick per sensor frame)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bus",
        type=bus_option,
        metavar="SPEC",
        required=True,
        help="bus spec (socketcan:vcan0, udp:GROUP@PORT, virtual:NAME, ...)",
    )
    parser.add_argument(
        "--mode",
        choices=("lockstep", "realtime"),
        default="lockstep",
        help="lockstep: one tick per PlantSensors frame (default); realtime: "
        "the node's own wall-clock rate",
    )
    parser.add_argument("--preset", default="default", help="parameter preset (ecu.params)")
    parser.add_argument(
        "--controller",
        choices=CONTROLLERS,
        help="override the preset's controller",
    )
    parser.add_argument(
        "--reading",
        choices=("printed", "reproducing"),
        help="how the document's gains are read (ecu.params.READINGS; default: the preset's)",
    )
    parser.add_argument(
        "--rate", type=option(integer=True, ecu_rate_hz=True), metavar="HZ",
        help="override the tick rate (50-1000, a divisor of the plant's 1 kHz)",
    )  # fmt: skip
    parser.add_argument(
        "--ticks", type=option(integer=True, positive=True), metavar="N",
        help="stop after answering N ticks",
    )  # fmt: skip
    parser.add_argument(
        "--guard",
        type=option(positive=True, hi=3600.0),
        default=1.0,
        metavar="S",
        help="lockstep: wall-clock guard for a missing frame (default 1 s)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override one ECU parameter (ecu.params.EcuParams field), repeatable",
    )
    parser.add_argument(
        "--commission",
        type=input_option,
        metavar="FILE",
        help="trim point and initial estimates from `sil identify --export` (read at start)",
    )
    parser.add_argument(
        "--ready-file",
        type=Path,
        metavar="PATH",
        help="create this file once the node listens on the bus (for launchers)",
    )
    parser.add_argument(
        "--start-file",
        type=Path,
        metavar="PATH",
        help="wait until this file exists before the first tick, and hear only the run's "
        "senders it names (a launcher writes it when every node is ready)",
    )
    parser.add_argument(
        "--impl",
        choices=("python", "c", "pil"),
        default="python",
        help="tick implementation: Python firmware, its C port (ecu/port, built at first use) or "
        "processor in the loop: the C firmware image on an emulated Cortex-M4 (QEMU "
        "mps2-an386), bridged over its CAN link (--pil-link)",
    )
    add_pil_link(parser, "--impl pil")
    parser.add_argument(
        "--serial",
        metavar="PORT",
        help="serve the service port on PORT: a device, 'pty' (a new pseudo-terminal, whose path "
        "is printed) or a pyserial URL (socket://HOST:PORT, rfc2217://...)",
    )
    parser.add_argument(
        "--flash",
        type=Path,
        metavar="FILE",
        help="emulated flash image holding the stored parameter set and the logbook (made when "
        "missing or empty; any other file must be such an image; locked while the ECU runs)",
    )
    parser.add_argument(
        "--xcp-ids",
        type=xcp_ids,
        metavar="MASTER,ECU",
        help="the XCP slave's CAN IDs, master to ECU and ECU to master (default: the DBC's "
        "XcpCommand and XcpResponse, 0x700,0x701)",
    )
    parser.add_argument(
        "--no-xcp",
        action="store_true",
        help="no XCP slave (default: one; --impl c and pil run the C slave, ecu/port/ecu_xcp.c; "
        "--impl c with --serial has none)",
    )
    add_launcher_options(parser)
    parser.add_argument("--json", action="store_true", help="print the run summary as JSON")


def _param(text: str) -> tuple[str, float]:
    from dataclasses import fields

    from ecu.params import EcuParams

    name, sep, value = text.partition("=")
    try:
        if not sep:
            raise ValueError
        number = float(value)
    except ValueError:
        raise ValueError(f"--param {text!r}: expected NAME=NUMBER") from None
    known = {f.name for f in fields(EcuParams)} - {"controller", "reading"}
    if name.strip() not in known:
        raise ValueError(f"--param {text!r}: {name.strip()!r} is not an ECU parameter")
    if not math.isfinite(number):
        raise ValueError(f"--param {text!r}: expected a finite number")
    return name.strip(), number


def run(args: argparse.Namespace) -> int:
    from ecu import commissioning
    from ecu.firmware_params import compile_params
    from ecu.node import EcuNode
    from ecu.params import ParamError, preset
    from protocol.bus import BusSpecError, open_bus
    from protocol.codec import Codec
    from protocol.node import listen_for, realtime_scheduling, run_lockstep, run_realtime
    from protocol.run_bus import RunBus

    try:
        overrides: dict[str, object] = dict(_param(p) for p in args.param)
    except ValueError as exc:
        print(f"sil ecu: {exc}", file=sys.stderr)
        return 2
    # the C node (--impl c) carries the C slave; with --serial the Python node runs the C core
    # with its service port, and no slave
    xcp_on = not args.no_xcp and not (args.impl == "c" and args.serial)
    if args.xcp_ids is not None and not xcp_on:
        print("sil ecu: --xcp-ids: no XCP slave runs (--no-xcp, or --impl c with --serial)",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.impl == "pil" and (args.serial or args.flash):
        print("sil ecu: --impl pil: the image has no service port (--serial, --flash)",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.controller:
        overrides["controller"] = args.controller
    if args.rate:
        overrides["rate_hz"] = args.rate
    if args.reading:
        overrides["reading"] = args.reading
    try:
        params = preset(args.preset, **overrides)
        if args.commission:
            params = commissioning.apply(params, commissioning.load(args.commission))
        booted = None
        if args.serial or args.flash or xcp_on:
            # the stored set, if any, over the preset and overrides
            from ecu.service.port import boot

            booted = boot(params, args.flash)
            params = booted.table.params
        params = compile_params(params)
    except (ParamError, ValueError, TypeError, OSError) as exc:
        print(f"sil ecu: {exc}", file=sys.stderr)
        return 2
    if args.ticks is not None and args.ticks < 1:
        print("sil ecu: --ticks must be at least 1", file=sys.stderr)
        return 2
    if args.impl == "pil":
        return _run_pil(args, params, booted if xcp_on else None)
    from ecu.port.build import PortBuildError
    from ecu.port.core import PortError, make_ecu

    try:
        ecu = make_ecu(args.impl, params)
        codec = Codec()
        lockstep = args.mode == "lockstep"
        if args.impl == "c" and not args.serial:  # the C node, with the C XCP slave
            node = _c_node(ecu, booted if xcp_on else None, args, codec)
        else:
            node = EcuNode(ecu=ecu, lockstep=lockstep, max_ticks=args.ticks, codec=codec)
        if booted is not None and booted.flash is not None:
            _logbook_in_flash(node, booted)
    except (PortBuildError, PortError, ValueError) as exc:
        print(f"sil ecu: --impl {args.impl}: {exc}", file=sys.stderr)
        return 2
    sequence = run_sequence(args, codec, "ECU", params.rate_hz)
    if args.serial and booted is not None:
        from ecu.service.port import ServicePort
        from ecu.service.transport import TransportError, open_transport

        try:
            node.service = ServicePort(open_transport(args.serial), node.ecu, booted)
        except TransportError as exc:
            print(f"sil ecu: {exc}", file=sys.stderr)
            return 2
        print(f"service port: {node.service.transport.name}", file=sys.stderr, flush=True)
    if xcp_on and booted is not None and args.impl == "python":
        _attach_xcp(node, booted, args)
    try:
        bus = RunBus(open_bus(args.bus), args.run_tag, sequence)
    except (BusSpecError, ValueError) as exc:
        print(f"sil ecu: {exc}", file=sys.stderr)
        return 2
    if not args.ready_file:  # a bench's ECU (a run's nodes are kept to the run by its bus)
        node.watch_bus(_say)  # another ECU on the bus: this one stays silent, or reports it
    listen_for(node, bus)  # its filters set before it says it is ready
    if node.xcp is not None:  # said once the node listens: a master may connect from now on
        x = node.xcp
        print(f"xcp: CAN IDs 0x{x.cmd_id:03X} (master) 0x{x.res_id:03X} (ECU)", file=sys.stderr,
              flush=True)  # fmt: skip
    stop = NodeStop()  # SIGTERM (or the run's end) ends the run cleanly, with the summary
    _stop_on_ctrl_c(stop)
    lost = PeerLost(on_lost=bus.relax)
    if args.ready_file:
        say_ready(args.ready_file, bus)
    if args.start_file:
        wait_to_start(args.start_file, bus, stop.is_set)
    try:
        if args.mode == "lockstep":
            guard = lost.guard(args.guard)
            stats = run_lockstep(node, bus, guard_s=guard, should_stop=stop.is_set)
        else:
            policy = realtime_scheduling()
            stats = run_realtime(node, bus, 1.0 / params.rate_hz, should_stop=stop.is_set)
            stats.scheduling = policy
    finally:
        bus.shutdown()
        if node.service is not None:
            node.service.transport.close()
        if booted is not None and booted.flash is not None:
            _save_logbook_at_stop(node)
            booted.flash.close()
    o = node.ecu.out
    summary = {
        "ticks": node.ticks,
        "mode": o.mode,
        "fault_word": o.fault_word,
        "sat_events": o.sat_events,
        **stats.summary(),
        **bus.stats(),
        "ticks_without_due_demand": node.demand_waits,
        **(node.watch.summary() if node.watch is not None else {}),
    }
    if node.service is not None:
        summary["service"] = node.service.summary()
    if node.xcp is not None:
        summary["xcp"] = node.xcp.summary()
    code = _report(summary, args)
    refused = node.watch is not None and node.watch.refused is not None
    return 2 if refused else code  # (said when it refused)


def _say(text: str) -> None:
    print(f"sil ecu: {text}", file=sys.stderr, flush=True)


def _stop_on_ctrl_c(stop: NodeStop) -> None:
    """Ctrl-C stops the node as SIGTERM does, after its tick (the logbook saved, the summary
    printed); a second Ctrl-C interrupts at once."""
    import signal
    import threading

    def interrupt(*_: object) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, interrupt)


def _save_logbook_at_stop(node) -> None:  # noqa: ANN001
    """An orderly stop: what the firmware has counted and its flash image does not hold yet
    (a run or a cool-down under way) saved now, said on stderr."""
    saver = node.logbook_saver
    if saver is None:
        return
    try:
        slot = saver.at_stop()
    except (OSError, ValueError) as exc:
        print(f"sil ecu: {saver.flash.path}: the logbook could not be saved at stop: {exc}",
              file=sys.stderr)  # fmt: skip
        return
    if slot is not None:
        print(f"logbook: saved at stop into {saver.flash.path} (slot {slot.index}, sequence "
              f"{slot.sequence})", file=sys.stderr, flush=True)  # fmt: skip


def _attach_xcp(node, booted, args: argparse.Namespace) -> None:  # noqa: ANN001
    """The XCP slave on the node: on the DBC's IDs or --xcp-ids, sharing the service port's
    bench when there is one; in real time its clock is the wall clock since start-up."""
    import time

    from ecu.xcp.slave import XcpSlave
    from protocol.dbc import xcp_frame_ids

    ids = args.xcp_ids or xcp_frame_ids()
    clock_us = None
    if args.mode == "realtime":
        start_ns = time.monotonic_ns()

        def clock_us() -> int:
            return (time.monotonic_ns() - start_ns) // 1000

    bench = node.service.bench_control if node.service is not None else None
    node.attach_xcp(XcpSlave(node.ecu, booted, bench, ids=ids, clock_us=clock_us))


def _logbook_in_flash(node, booted) -> None:  # noqa: ANN001
    """The engine's logbook from the stored set into the firmware (power-up), and its save at
    rest into the same flash image: beside the C slave's stores on the C node, else beside
    the service port's and the Python slave's saves."""
    from ecu.service import logbook_save

    for problem in logbook_save.load(node.ecu, booted.payload):
        print(f"sil ecu: {problem}", file=sys.stderr)
    store = getattr(node.xcp, "store", None)
    if store is not None:  # the C slave's flash store: the saver on the same image
        store.saver = node.logbook_saver = logbook_save.LogbookSaver(
            node.ecu, store.flash, store.image, busy=lambda: store.writer is not None
        )
    else:
        node.logbook_saver = logbook_save.boot_saver(node.ecu, booted)


def _wall_clock_us():  # noqa: ANN202
    """The ECU's clock in real time: microseconds of the wall clock since start-up."""
    import time

    start_ns = time.monotonic_ns()
    return lambda: (time.monotonic_ns() - start_ns) // 1000


def _c_node(ecu, booted, args: argparse.Namespace, codec):  # noqa: ANN001, ANN202
    """The C node (ecu/port/ecu_node.c) on the C core; with ``booted`` (the set it runs and the
    flash image) the C XCP slave on it, on the DBC's IDs or --xcp-ids."""
    import os

    from ecu.port.node import CEcuNode
    from ecu.port.xcp import CXcpSlave
    from protocol.dbc import xcp_frame_ids

    node = CEcuNode(ecu, lockstep=args.mode == "lockstep", codec=codec, max_ticks=args.ticks)
    if booted is not None:
        slave = CXcpSlave(
            ecu, booted.table, ids=args.xcp_ids or xcp_frame_ids(),
            seed=int.from_bytes(os.urandom(4), "little") or 1,
            clock_us=_wall_clock_us() if args.mode == "realtime" else None, flash=booted.flash,
        )  # fmt: skip
        node.attach_xcp(slave)
    return node


def _run_pil(args: argparse.Namespace, params, booted) -> int:  # noqa: ANN001
    """The firmware image on QEMU, its CAN link bridged to the bus (ecu/port/pil.py); with
    ``booted`` (the set it runs) the image's XCP slave on the DBC's IDs or --xcp-ids."""
    import os

    from ecu.node import RECEIVED, OtherEcuWatch
    from ecu.port.build import PortBuildError
    from ecu.port.pil import PilError, PilImage, XcpBlock, calibration_block, image_sizes
    from ecu.port.pil_bridge import PilBridge
    from ecu.port.xcp_run import run_record
    from protocol.bus import BusSpecError, open_bus
    from protocol.codec import Codec
    from protocol.dbc import xcp_frame_ids
    from protocol.node import realtime_scheduling
    from protocol.run_bus import RunBus

    lockstep = args.mode == "lockstep"  # profiled by instruction counting (ecu/port/pil.py)
    xcp = None
    if booted is not None:
        seed = int.from_bytes(os.urandom(4), "little") or 1
        xcp = XcpBlock(args.xcp_ids or xcp_frame_ids(), seed, run_record(booted.table))
    block = calibration_block(
        params, lockstep=lockstep, guard_s=args.guard, profile=lockstep, xcp=xcp
    )
    codec = Codec()
    frame_ids = [codec[m].frame_id for m in RECEIVED] + ([xcp.ids[0]] if xcp else [])
    stop = NodeStop()
    PeerLost()  # (the image keeps its guard: told its peer is gone, the process stays)
    try:
        image = PilImage(block, link=args.pil_link, icount=lockstep)
    except (PortBuildError, PilError) as exc:
        print(f"sil ecu: --impl pil: {exc}", file=sys.stderr)
        return 2
    try:
        bus = RunBus(
            open_bus(args.bus), args.run_tag, run_sequence(args, codec, "ECU", params.rate_hz)
        )
    except (BusSpecError, ValueError) as exc:
        print(f"sil ecu: {exc}", file=sys.stderr)
        return 2
    bridge = None
    # in real time the bridge and QEMU (which inherits it) at the nodes' real-time scheduling:
    # the image's periods come on time on a machine busy with other work
    policy = None if lockstep else realtime_scheduling()
    try:
        image.start()
        image_bus = image.open_bus()
        try:
            image.wait_ready()
            print(f"pil: image {image.elf.name} on {image.url}", file=sys.stderr, flush=True)
            bench = not args.ready_file  # (a run's nodes are kept to the run by its bus)
            watch = OtherEcuWatch(codec, params.rate_hz, lockstep, _say) if bench else None
            actuator_id = codec["EcuActuator"].frame_id
            bridge = PilBridge(bus, image_bus, frame_ids, watch, actuator_id)
            if xcp is not None:  # said once the bridge listens: a master may connect
                print(f"xcp: CAN IDs 0x{xcp.ids[0]:03X} (master) 0x{xcp.ids[1]:03X} (ECU)",
                      file=sys.stderr, flush=True)  # fmt: skip
            if args.ready_file:
                say_ready(args.ready_file, bus)
            if args.start_file:
                wait_to_start(args.start_file, bus, stop.is_set)
            limit = args.ticks

            def should_stop() -> bool:
                done = limit is not None and image.profile.ticks >= limit
                return stop.is_set() or done or image.exit_code() is not None

            bridge.run(should_stop)
            if (code := image.exit_code()) is not None and not stop.is_set():
                raise PilError(f"the emulator exited with code {code} while the image ran")
        finally:
            image_bus.shutdown()
    except PilError as exc:
        print(f"sil ecu: --impl pil: {exc}", file=sys.stderr)
        return 2
    finally:
        image.stop()
        bus.shutdown()
    summary = {
        "impl": "pil",
        **({"ticks": image.profile.ticks} if lockstep else {"scheduling": policy}),
        **(bridge.stats() if bridge is not None else {}),
        **bus.stats(),
        "pil": {**image.profile.summary(), "image": image_sizes(image.elf)},
        **({"xcp": {"impl": "pil", "ids": list(xcp.ids)}} if xcp is not None else {}),
    }
    code = _report(summary, args)
    return 2 if bridge is not None and bridge.silenced else code  # (said when it refused)


def _report(summary: dict, args: argparse.Namespace) -> int:
    """The run summary into --stats-file and on stdout (as JSON with --json)."""
    if args.stats_file is not None:
        args.stats_file.write_text(strict_json.dumps(summary, indent=2) + "\n")
    if args.json:
        print(strict_json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            print(f"{key}: {value}")
    return 0
