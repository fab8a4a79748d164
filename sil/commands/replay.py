"""`sil replay LOG`: decode a CAN log (--dry-run) or play it onto a bus in real time."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from protocol import strict_json
from protocol.bus import BusSpecError, default_spec, open_bus, parse_spec
from sil import validation
from sil.record import replay
from sil.record.canlog import LogReadError, read_frames
from sil.record.results import REPLAY_FILES, WriteError, named, write_atomically, write_with
from sil.run import run_folder

NAME = "replay"
HELP = (
    "decode a CAN log (candump, ASC, BLF, TRC, CSV, MF4), play it onto a bus in real time, or "
    "into the ECU emulator"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "log", type=validation.input_option, help="the log file (format detected from its content)"
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print the decoded frames instead of sending them"
    )
    parser.add_argument(
        "--bus", type=validation.bus_option, metavar="SPEC",
        help="bus to play onto (default as in protocol)",
    )  # fmt: skip
    parser.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    parser.add_argument("--loop", action="store_true", help="play the log again and again")
    parser.add_argument(
        "--skip-gaps", type=float, metavar="SECONDS", help="shorten pauses longer than this to this"
    )
    parser.add_argument("--ids", metavar="FILTER", help="only these IDs: 0x100,0x110-0x1FF")
    parser.add_argument(
        "--into-ecu",
        action="store_true",
        help="drive the ECU emulator with the log's sensor and demand frames "
        "and compare its frames with the recorded ones",
    )
    parser.add_argument(
        "--scenario",
        type=Path,
        help="--into-ecu: the run's scenario for the ECU parameters (default: "
        "scenario.toml beside the log)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="--into-ecu: change an ECU parameter (e.g. to check a change)",
    )
    parser.add_argument(
        "--out", metavar="DIR", help="--into-ecu: folder for report.json and a plot"
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")


def _print_report(report: dict, as_json: bool) -> None:
    if as_json:
        print(strict_json.dumps(report, indent=2))
        return
    for key, value in report.items():
        print(f"{key}: {value}")


def _dry_run(args: argparse.Namespace, keep) -> int:
    """Every frame decoded, then the report; exit 1 if the log is truncated or corrupt, or holds
    frames of our messages with a wrong length (each kind named once, with its first position)."""
    decoder = replay.Decoder()
    error = None
    first_seen: dict[str, str] = {}  # wrong-length problem -> position of its first frame
    reader = read_frames(args.log)
    try:
        for msg in reader:
            if not keep(msg.arbitration_id):
                continue
            signals = decoder.decode(msg)
            if decoder.problem is not None:
                first_seen.setdefault(decoder.problem, reader.position)
            if args.json:
                continue
            if signals is not None:
                name = decoder.codec.by_id[msg.arbitration_id].name
                values = " ".join(f"{k}={v:g}" for k, v in signals.items())
                print(f"{msg.timestamp:12.6f} {msg.arbitration_id:03X} {name} {values}")
            else:
                kind = decoder.problem or replay.skip_reason(msg) or "unknown ID"
                print(
                    f"{msg.timestamp:12.6f} {msg.arbitration_id:03X} ({kind}) "
                    f"{bytes(msg.data).hex()}"
                )
    except LogReadError as exc:
        error = exc
    report = decoder.stats.as_dict()
    if error is not None:
        report["error"] = str(error)
    _print_report(report, args.json)
    for problem, position in first_seen.items():
        count = decoder.stats.wrong_length[problem]
        print(f"sil replay: {args.log}: {position}: {problem} ({count} frames)", file=sys.stderr)
    if error is not None:
        print(f"sil replay: {error}", file=sys.stderr)
    return 1 if error is not None or first_seen else 0


def _into_ecu(args: argparse.Namespace) -> int:
    """The log into the ECU emulator, set up as the run that wrote it (its folder's record:
    scenario as run, commissioning, ECU implementation); exit 1 when the ECU's frames differ."""
    from ecu.params import ParamError
    from ecu.port.build import PortBuildError
    from ecu.port.core import PortError
    from sil import scenario as scenarios
    from sil.run.run_record import load as load_record

    try:
        out = run_folder.out_path("--out", args.out)
        if out is not None:
            run_folder.check("--out", out)
        record = load_record(args.log.parent)
        path = args.scenario or (record.scenario if record else args.log.parent / "scenario.toml")
        if record is not None and record.mode == "realtime":
            raise ValueError(
                f"{args.log}: a real-time run (run.json): its ECU ran on its own clock, from "
                "before the recording began, so its log cannot be replayed tick for tick"
            )
        s = scenarios.load(path)
        node, setup = _ecu_for(s, record, args.param)
        report = replay.into_ecu(args.log, node)
    except (scenarios.ScenarioError, ParamError, ValueError, TypeError) as exc:  # (FolderError)
        print(f"sil replay: {exc}", file=sys.stderr)
        return 2
    except (PortBuildError, PortError) as exc:
        print(f"sil replay: the run's C ECU: {exc}", file=sys.stderr)
        return 2
    except LogReadError as exc:
        print(f"sil replay: {exc}", file=sys.stderr)
        return 1
    result = {"log": str(args.log), "scenario": str(path), **setup, **report.as_dict()}
    if out is not None:
        try:
            _write_report(out, result, report, args.log.name)
        except run_folder.FolderError as exc:
            print(f"sil replay: {exc}", file=sys.stderr)
            return 2
        except WriteError as exc:
            print(f"sil replay: {exc}", file=sys.stderr)
            return 1
    _print_report(result, args.json)
    verdict = report.verdict()
    if verdict is not None:
        print(f"sil replay: {args.log}: {verdict}", file=sys.stderr)
        return 1
    return 0


def _write_report(out: Path, result: dict, report: replay.EcuComparison, title: str) -> None:
    """report.json and into_ecu.png into ``out``, locked while written (FolderError: another
    command holds it), an earlier replay's removed first, each written atomically
    (WriteError names a file that could not be)."""
    with run_folder.FolderLock(out):
        for name in REPLAY_FILES:
            with named(out / name):
                (out / name).unlink(missing_ok=True)
        write_atomically(out / "report.json", strict_json.dumps(result, indent=2) + "\n")
        _plot_comparison(report, out / "into_ecu.png", title)


def _ecu_for(s, record, param_texts: list[str]):  # noqa: ANN001, ANN202 (Scenario, RunRecord)
    """The ECU node for a replay of a run of ``s`` (``record``: its folder's, or None) with
    ``--param`` changes, and what set it up (for the report)."""
    from dataclasses import replace

    from ecu import commissioning
    from ecu.firmware_params import compile_params
    from ecu.node import EcuNode
    from ecu.port.core import make_ecu
    from sil.commands.ecu import _param
    from sil.run.config import build_plant, ecu_params

    params = ecu_params(s, build_plant(s, s.seed))
    commissioned = record.commissioning if record is not None else None
    if commissioned is not None:
        params = commissioning.commission(params, commissioned)
    changes = dict(_param(p) for p in param_texts)
    params = compile_params(replace(params, **changes))
    impl = "python" if record is None else record.ecu_impl
    impl = "c" if impl == "pil" else impl  # the image is the C firmware, bit for bit
    setup = {
        "run_record": None if record is None else str(record.folder / "run.json"),
        "commissioning": None if commissioned is None else str(commissioned),
        "ecu_impl": impl,
        "changed": changes,
    }
    return EcuNode(ecu=make_ecu(impl, params)), setup


def _plot_comparison(report: replay.EcuComparison, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, recorded, replayed = report.series.get("PumpVoltageTarget", ([], [], []))
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    ax.plot(t, recorded, lw=1, label="recorded ECU")
    ax.plot(t, replayed, "--", lw=1, label="ECU emulator now")
    ax.set_ylabel("pump voltage [V]")
    ax.set_title(f"{title}: first divergent tick {report.first_divergent_tick}")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax2.plot(t, [b - a for a, b in zip(recorded, replayed, strict=True)], color="tab:red", lw=1)
    ax2.set_ylabel("difference [V]")
    ax2.set_xlabel("time [s]")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    try:
        write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        plt.close(fig)


def run(args: argparse.Namespace) -> int:
    if not args.log.is_file():
        print(f"sil replay: {args.log}: no such file", file=sys.stderr)
        return 2
    try:
        keep = replay.id_filter(args.ids)
    except ValueError as exc:
        print(f"sil replay: {exc}", file=sys.stderr)
        return 2
    try:
        validation.number("sil replay", "--speed", args.speed, lo=0.001, hi=1000)
        if args.skip_gaps is not None:
            validation.number("sil replay", "--skip-gaps", args.skip_gaps, lo=0)
    except validation.InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    if args.dry_run:
        return _dry_run(args, keep)
    if args.into_ecu:
        return _into_ecu(args)
    try:
        if args.bus:
            spec = parse_spec(args.bus)
        else:
            spec, why = default_spec()
            print(why, file=sys.stderr)
        bus = open_bus(spec)
    except BusSpecError as exc:
        print(f"sil replay: {exc}", file=sys.stderr)
        return 2
    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    error = None
    try:
        report = replay.play(
            args.log,
            bus,
            speed=args.speed,
            loop=args.loop,
            skip_gaps=args.skip_gaps,
            keep=keep,
            should_stop=lambda: stop["now"],
        ).as_dict()
    except LogReadError as exc:
        error, report = exc, {"sent": "see error"}
    except KeyboardInterrupt:
        report = {"interrupted": True}
    finally:
        bus.shutdown()
    if error is not None:
        report["error"] = str(error)
    _print_report({"bus": str(spec), **report}, args.json)
    if error is not None:
        print(f"sil replay: {error}", file=sys.stderr)
        return 1
    return 0
