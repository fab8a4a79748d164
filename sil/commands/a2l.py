"""`sil a2l [--out FILE] [--impl python|c|pil]`: the ECU's A2L (ASAM MCD-2 MC 1.7) for
calibration and measurement tools (CANape, INCA, pyXCP with pya2ldb), written from the tables its
XCP slave serves, with the limits of the implementation's slave."""

from __future__ import annotations

import argparse
import sys

from sil import validation
from sil.run.node_options import xcp_ids
from sil.validation import option

NAME = "a2l"
HELP = "write the ECU's A2L (parameters, measurements, XCP on CAN) for calibration tools"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        type=validation.path_option,
        metavar="FILE",
        help="write it to FILE (default: standard output)",
    )
    parser.add_argument(
        "--rate", type=option(integer=True, ecu_rate_hz=True), metavar="HZ",
        help="the ECU's tick rate, the control-tick event's cycle (default: 100)",
    )  # fmt: skip
    parser.add_argument(
        "--impl",
        choices=("python", "c", "pil"),
        default="python",
        help="the ECU implementation the tool will attach to: the C slave (c, pil) takes smaller "
        "master blocks and fewer DAQ lists (default: python)",
    )
    parser.add_argument(
        "--xcp-ids",
        type=xcp_ids,
        metavar="MASTER,ECU",
        help="the XCP slave's CAN IDs as `sil ecu --xcp-ids` gives them (default: the DBC's)",
    )


def text_for(impl: str, rate_hz: int | None, ids: tuple[int, int] | None) -> str:
    """The A2L of the ECU implementation ``impl`` (its slave's limits; the C slave's and the
    image's READ_ONLY parameters, which their targets do not recompute) at ``rate_hz``, with
    the XCP identifiers ``ids`` (None: the DBC's)."""
    from ecu.params import EcuParams
    from ecu.port.xcp import header_limits
    from ecu.port.xcp_run import writable
    from ecu.service.param_table import TABLE
    from ecu.xcp.a2l import a2l_text
    from ecu.xcp.slave import Limits
    from protocol.dbc import xcp_frame_ids

    if impl == "python":
        return a2l_text(rate_hz, ids or xcp_frame_ids(), Limits())
    params = EcuParams() if rate_hz is None else EcuParams(rate_hz=rate_hz)
    fixed = frozenset(spec.name for spec in TABLE) - writable(params)  # (computed on the host)
    return a2l_text(rate_hz, ids or xcp_frame_ids(), header_limits(), fixed)


def run(args: argparse.Namespace) -> int:
    text = text_for(args.impl, args.rate, args.xcp_ids)
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
