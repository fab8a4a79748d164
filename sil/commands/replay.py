"""`sil replay LOG`: decode a CAN log (--dry-run) or play it onto a bus in real time."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from protocol.bus import BusSpecError, default_spec, open_bus, parse_spec
from sil.canlog import LogReadError, read_frames
from tools import replay

NAME = "replay"
HELP = "decode a CAN log (candump, ASC, BLF, TRC, CSV) or play it onto a bus in real time"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", type=Path, help="the log file (format detected from its content)")
    parser.add_argument(
        "--dry-run", action="store_true", help="print the decoded frames instead of sending them"
    )
    parser.add_argument("--bus", metavar="SPEC", help="bus to play onto (default as in protocol)")
    parser.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    parser.add_argument("--loop", action="store_true", help="play the log again and again")
    parser.add_argument(
        "--skip-gaps", type=float, metavar="SECONDS", help="shorten pauses longer than this to this"
    )
    parser.add_argument("--ids", metavar="FILTER", help="only these IDs: 0x100,0x110-0x1FF")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")


def _print_report(report: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(report, indent=2))
        return
    for key, value in report.items():
        print(f"{key}: {value}")


def _dry_run(args: argparse.Namespace, keep) -> int:
    decoder = replay.Decoder()
    error = None
    try:
        for msg in read_frames(args.log):
            if not keep(msg.arbitration_id):
                continue
            signals = decoder.decode(msg)
            if args.json:
                continue
            if signals is not None:
                name = decoder.codec.by_id[msg.arbitration_id].name
                values = " ".join(f"{k}={v:g}" for k, v in signals.items())
                print(f"{msg.timestamp:12.6f} {msg.arbitration_id:03X} {name} {values}")
            else:
                kind = replay.skip_reason(msg) or "unknown ID"
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
    if error is not None:
        print(f"sil replay: {error}", file=sys.stderr)
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    if not args.log.is_file():
        print(f"sil replay: {args.log}: no such file", file=sys.stderr)
        return 2
    try:
        keep = replay.id_filter(args.ids)
    except ValueError as exc:
        print(f"sil replay: {exc}", file=sys.stderr)
        return 2
    if args.dry_run:
        return _dry_run(args, keep)
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
