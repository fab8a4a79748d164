"""`sil log convert IN OUT`: a CAN log in another format (candump, ASC, BLF, TRC, python-can
CSV, MF4), keeping its absolute start (sil/record/canlog.py, sil/record/mdf.py; docs/replay.md)."""

from __future__ import annotations

import argparse
import sys

from protocol import strict_json
from sil import validation

NAME = "log"
HELP = "convert a CAN log between candump, ASC, BLF, TRC, CSV and MF4 (ASAM MDF 4 bus logging)"
CONVERT = (
    "convert a CAN log into the format OUT's suffix names (.log candump, .asc, .blf, .trc, .csv, "
    ".mf4), keeping its absolute start; the input's format is read from its content"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    convert = actions.add_parser("convert", help=CONVERT, description=CONVERT)
    convert.add_argument(
        "source", type=validation.input_option, metavar="IN", help="the log to convert"
    )
    convert.add_argument(
        "target", type=validation.path_option, metavar="OUT", help="the log to write"
    )
    convert.add_argument(
        "--start",
        metavar="TIME",
        help="the log's absolute start, as epoch seconds or ISO 8601 (2026-12-06T21:56:03Z); "
        "default: epoch times' first frame, an MF4's or ASC file's header, a run's start "
        "(run.json beside the log), else the file's modification time",
    )
    convert.add_argument("--json", action="store_true", help="print what was done as JSON")


def run(args: argparse.Namespace) -> int:
    from sil.record.canlog import LogReadError, convert_log
    from sil.record.mdf import MdfUnavailable, parse_start
    from sil.record.results import WriteError

    prefix = "sil log convert"
    if not args.source.is_file():
        print(f"{prefix}: {args.source}: no such file", file=sys.stderr)
        return 2
    if args.target.exists() and args.target.resolve() == args.source.resolve():
        print(f"{prefix}: {args.target}: is the input; write to another file", file=sys.stderr)
        return 2
    try:
        start = None if args.start is None else parse_start(args.start)
    except ValueError as exc:
        print(f"{prefix}: --start: {exc}", file=sys.stderr)
        return 2
    try:
        done = convert_log(args.source, args.target, start_s=start)
    except (ValueError, LogReadError, MdfUnavailable) as exc:  # nothing was written
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 2
    except WriteError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(strict_json.dumps(done, indent=2))
    else:
        print(
            f"{prefix}: {done['source']} ({done['source_format']}) -> {done['target']} "
            f"({done['target_format']}): {done['frames']:,} frames, start {done['start']} "
            f"(from {done['start_from']})",
            file=sys.stderr,
        )
    return 0
