"""`sil run SCENARIO`: plant and ECU as separate CAN nodes (or in one process), recorded."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from protocol import strict_json
from protocol.bus import BusSpecError
from protocol.run_tag import TagsExhausted
from sil import scenario as scenarios
from sil.record import results
from sil.record.canlog import EXTRA_FORMATS
from sil.record.mdf import require as require_mdf
from sil.run import run_folder
from sil.run.node_options import add_pil_link
from sil.run.run_record import Overrides
from sil.run.watchdog import Terminated, interrupt_reason
from sil.validation import bus_option, input_option

NAME = "run"
HELP = "run a scenario: plant and ECU nodes over a bus (or in one process), with results"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="a shipped scenario's name (sil scenarios) or a file")
    add_run_options(parser)
    add_controller_options(parser)


def add_controller_options(parser: argparse.ArgumentParser) -> None:
    """Changes to the scenario's controller, recorded in the run folder (run.json and the
    scenario.toml written there)."""
    from ecu.params import CONTROLLERS, PRESETS, READINGS

    parser.add_argument("--controller", choices=CONTROLLERS, help="the scenario's controller kind")
    parser.add_argument(
        "--preset", choices=sorted(PRESETS), help="the ECU parameter preset (ecu.params)"
    )
    parser.add_argument(
        "--reading", choices=READINGS, help="how the document's gains are read (ecu.params)"
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override one ECU parameter (an ecu.params.EcuParams field), repeatable",
    )


def overrides(args: argparse.Namespace) -> Overrides:
    """The controller changes on the command line; ValueError names a bad --param."""
    from sil.commands.ecu import _param

    return Overrides(
        controller=getattr(args, "controller", None),
        preset=getattr(args, "preset", None),
        reading=getattr(args, "reading", None),
        params=dict(_param(text) for text in getattr(args, "param", [])),
    )


def add_run_options(parser: argparse.ArgumentParser, out_default: str = "out/SCENARIO") -> None:
    parser.add_argument(
        "--bus",
        type=bus_option,
        metavar="SPEC",
        help="bus spec (default: vcan0 if up, else a loopback bus of this run's own)",
    )
    parser.add_argument(
        "--ecu-bus",
        type=bus_option,
        metavar="SPEC",
        help="with [[bus_fault]] on a bus: the ECU's bus behind the fault bridge "
        "(default: a second loopback bus)",
    )
    parser.add_argument(
        "--mode",
        choices=("lockstep", "realtime", "inproc"),
        default="lockstep",
        help="lockstep (default): the plant owns time; realtime: wall clock; "
        "inproc: all nodes in this process, no bus",
    )
    parser.add_argument(
        "--out", metavar="DIR", help=f"output folder (default: {out_default}; '.' for this one)"
    )
    parser.add_argument("--seed", type=int, help="noise seed (default: the scenario's)")
    parser.add_argument(
        "--log-format",
        action="append",
        choices=EXTRA_FORMATS,
        default=[],
        help="also write can.log as .asc, .blf or .mf4 (MF4 with the run's start; repeatable)",
    )
    parser.add_argument(
        "--commission",
        type=input_option,
        metavar="FILE",
        help="ECU trim point and initial estimates (sil identify --export)",
    )
    parser.add_argument(
        "--ecu-impl",
        choices=("python", "c", "pil"),
        default="python",
        help="ECU tick implementation: the Python firmware, its C port (ecu/port) or the C "
        "firmware image on an emulated Cortex-M4 (pil: processor in the loop, on a bus)",
    )
    add_pil_link(parser, "--ecu-impl pil")
    parser.add_argument(
        "--python-loop",
        action="store_true",
        help="inproc with the C ECU: carry the frames between the nodes in Python (the same "
        "files, 3-4x slower) instead of the compiled loop",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def print_summary(summary: dict, out: Path) -> None:
    keys = (
        "status",
        "abort_reason",
        "mode",
        "bus",
        "run_tag",
        "foreign_frames",
        "sim_time_s",
        "wall_time_s",
        "realtime_factor",
        "frames",
        "bus_load_pct",
        "missed_ticks",
        "tracking_rms_pct",
        "tracking_speed_loop_rms_pct",
        "max_egt_K",
        "egt_limit_time_s",
        "start_time_s",
        "start_egt_peak_K",
        "start_abort",
        "start_abort_s",
        "relights",
        "unburnt_fuel_kg",
        "cool_down_s",
        "final_egt_K",
    )
    for key in keys:
        value = summary.get(key)
        if value is None:
            continue
        print(f"{key:<18} {value:.4g}" if isinstance(value, float) else f"{key:<18} {value}")
    est = summary.get("estimates", {})
    if est:
        print("estimates          " + ", ".join(f"{k}={_fmt(v)}" for k, v in est.items()))
    for fault in summary.get("faults", []):
        print(f"fault              {fault['time_s']:.2f} s {fault['fault']}")
    print(f"results in         {out}")


def _fmt(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
    return f"{value:.4g}"


def _raise_interrupt(signum: int, frame: object) -> None:
    if signum == signal.SIGTERM:
        raise Terminated("SIGTERM")
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _interrupt_on_signals() -> None:
    """Ctrl-C and SIGTERM end the run cleanly (aborted summary, nodes stopped), even when the
    shell that started us ignores SIGINT, as non-interactive shells do for background jobs."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _raise_interrupt)
        signal.signal(signal.SIGTERM, _raise_interrupt)


def execute(scenario_ref: str, args: argparse.Namespace, out: Path | None = None) -> int:
    """Fly ``scenario_ref`` into ``out`` (default: ``--out``, else out/SCENARIO). Every input is
    checked before the folder is touched: a refusal (exit 2) leaves it as it was."""
    from sil.run.runner import RunOptions
    from sil.run.runner import run as run_scenario

    try:
        given = out or run_folder.out_path("--out", args.out)
        if given is not None:
            run_folder.check("--out", given)
        scenario = scenarios.load(scenario_ref)
        out = given or Path("out") / scenario.name
        run_folder.check("--out", out)
        changes = overrides(args)
        if "mf4" in args.log_format:
            require_mdf("--log-format mf4")  # ValueError without asammdf
    except (scenarios.ScenarioError, run_folder.FolderError, ValueError) as exc:
        print(f"sil run: {exc}", file=sys.stderr)
        return 2
    options = RunOptions(
        scenario,
        out,
        mode=args.mode,
        bus=args.bus,
        seed=args.seed,
        log_formats=tuple(args.log_format),
        commission=args.commission,
        plots=not args.no_plots,
        ecu_impl=getattr(args, "ecu_impl", "python"),
        pil_link=getattr(args, "pil_link", "eth"),
        ecu_bus=getattr(args, "ecu_bus", None),
        compiled_loop=not getattr(args, "python_loop", False),
        overrides=changes,
        command_line=tuple(getattr(args, "command_line", ())),
    )
    _interrupt_on_signals()
    try:
        summary = run_scenario(options)
    except (BusSpecError, ValueError) as exc:
        print(f"sil run: {exc}", file=sys.stderr)
        return 2
    except (results.WriteError, TagsExhausted) as exc:  # before the run began: a full disk, or
        print(f"sil run: {exc}", file=sys.stderr)  # as many runs on the bus as it can keep apart
        return 1
    except KeyboardInterrupt as exc:  # before the run began, or while it ended
        print(f"sil run: aborted: {interrupt_reason(exc)}", file=sys.stderr)
        return 1
    if args.json:
        print(strict_json.dumps(summary, indent=2, default=float))
    else:
        print_summary(summary, out)
    if summary["status"] != "completed":  # aborted, or touched by another sender
        print(f"sil run: {summary['status']}: {summary['abort_reason']}", file=sys.stderr)
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    return execute(args.scenario, args)
