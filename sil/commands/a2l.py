"""`sil a2l [--out FILE]`: the ECU's A2L (ASAM MCD-2 MC 1.7) for calibration and measurement
tools (CANape, INCA, pyXCP with pya2ldb), written from the tables its XCP slave serves."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sil.node_options import xcp_ids
from sil.validation import option

NAME = "a2l"
HELP = "write the ECU's A2L (parameters, measurements, XCP on CAN) for calibration tools"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", type=Path, metavar="FILE", help="write it to FILE (default: standard output)"
    )
    parser.add_argument(
        "--rate", type=option(integer=True, ecu_rate_hz=True), metavar="HZ",
        help="the ECU's tick rate, the control-tick event's cycle (default: 100)",
    )  # fmt: skip
    parser.add_argument(
        "--xcp-ids",
        type=xcp_ids,
        metavar="MASTER,ECU",
        help="the XCP slave's CAN IDs as `sil ecu --xcp-ids` gives them (default: the DBC's)",
    )


def run(args: argparse.Namespace) -> int:
    from ecu.xcp.a2l import a2l_text
    from protocol.dbc import xcp_frame_ids

    text = a2l_text(args.rate, args.xcp_ids or xcp_frame_ids())
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        args.out.write_text(text, encoding="latin-1")
    except OSError as exc:
        print(f"sil a2l: {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"sil a2l: {args.out}", file=sys.stderr)
    return 0
