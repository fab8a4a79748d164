"""`sil verify`: the ECU against the document's sec. 4.2 and 5.2 results (one process, no bus)."""

from __future__ import annotations

import argparse
import json

NAME = "verify"
HELP = "reproduce the document's estimator (sec. 4.2) and MRAC (sec. 5.2) results with the ECU"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument(
        "--seconds", type=float, default=300.0, help="simulated time per run (default 300)"
    )


def run(args: argparse.Namespace) -> int:
    from sil.verify import format_table, verification_rows

    if args.seconds <= 0.0:
        raise SystemExit("sil verify: --seconds must be > 0")
    rows = verification_rows(args.seconds)
    print(json.dumps(rows, indent=2) if args.json else format_table(rows))
    return 0 if all(r["ok"] for r in rows) else 1
