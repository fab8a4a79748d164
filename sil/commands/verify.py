"""`sil verify`: the document's published numbers, each reproduced or explained (one process)."""

from __future__ import annotations

import argparse
import sys

from protocol import strict_json

NAME = "verify"
HELP = "check every published number of the document against the ECU and plant, one row each"


# sil.verify.SECTIONS, kept here so that parsing the command line imports no runs (a test
# checks)
SECTIONS = ("trim", "identification", "sec4.2", "sec4.3", "sec5.2", "sec5.3", "controllers")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument(
        "--section",
        action="append",
        choices=SECTIONS,
        help="only this section (repeatable; default: all, in the document's order)",
    )
    parser.add_argument(
        "--seconds",
        type=float,
        help="override every run's duration (quick checks; the published numbers are read at "
        "each scenario's stated duration, the default)",
    )


def run(args: argparse.Namespace) -> int:
    import math

    from sil.verify import verification_rows
    from sil.verify.rows import as_dicts, format_table

    if args.seconds is not None and not (math.isfinite(args.seconds) and args.seconds > 0.0):
        print(
            f"sil verify: --seconds must be a positive number, got {args.seconds}",
            file=sys.stderr,
        )
        return 2
    sections = tuple(s for s in SECTIONS if s in args.section) if args.section else SECTIONS
    rows = verification_rows(args.seconds, sections)
    print(strict_json.dumps(as_dicts(rows), indent=2) if args.json else format_table(rows))
    return 0 if all(r.ok for r in rows) else 1
