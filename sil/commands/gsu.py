"""`sil gsu --bus SPEC [--port N] [--listen ADDR] [--a2l FILE]`: the ground-support page in the
browser, attached to a live ECU through its CAN frames and its XCP slave.

It prints the page's address (with the session's token) and serves until Ctrl-C; a recording
under way is written then.
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
from pathlib import Path

from sil import validation
from sil.commands import a2l as a2l_command
from sil.run import run_folder
from sil.run.node_options import xcp_ids
from sil.validation import bus_option, option

NAME = "gsu"
HELP = "the ground-support page in the browser: dashboard, start/stop, tests, parameters, logbook"
DEFAULT_PORT = 8470


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bus", type=bus_option, required=True, metavar="SPEC",
        help="the engine's bus: socketcan:vcan0, "
        "udp:GROUP[@PORT] as the ECU's, or any python-can interface:channel"
    )  # fmt: skip
    parser.add_argument(
        "--port",
        type=option(integer=True, lo=0, hi=65535),
        default=DEFAULT_PORT,
        metavar="N",
        help=f"the page's TCP port (default {DEFAULT_PORT}; 0: any free one)",
    )
    parser.add_argument(
        "--listen",
        default="127.0.0.1",
        metavar="ADDR",
        help="the address to listen on (default 127.0.0.1: this machine only; 0.0.0.0 opens the "
        "page to the network)",
    )
    parser.add_argument(
        "--a2l",
        type=validation.path_option,
        metavar="FILE",
        help="the ECU's A2L (default: the project's, as `sil a2l --impl IMPL` writes it)",
    )
    parser.add_argument(
        "--impl",
        choices=("python", "c", "pil"),
        default="python",
        help="without --a2l: the ECU implementation whose A2L to use (default: python)",
    )
    parser.add_argument(
        "--xcp-ids", type=xcp_ids, metavar="MASTER,ECU", help="the XCP slave's CAN IDs"
    )
    parser.add_argument(
        "--out",
        type=validation.path_option,
        default=Path("."),
        metavar="DIR",
        help="where recordings go (default: the current folder)",
    )


def _a2l(args: argparse.Namespace):  # noqa: ANN202 (sil.record.a2l.A2l)
    from sil.record.a2l import read_a2l

    if args.a2l is not None:
        return read_a2l(args.a2l)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "turbojet_ecu.a2l"
        path.write_text(a2l_command.text_for(args.impl, None, args.xcp_ids), "latin-1")
        return read_a2l(path)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    from protocol.bus import BusSpecError, parse_spec
    from protocol.dbc import xcp_frame_ids
    from sil.console.gsu.app import App
    from sil.record.a2l import A2lError

    prefix = "sil gsu"
    try:
        run_folder.check("--out", args.out)
    except run_folder.FolderError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 2
    if not args.out.is_dir():
        print(f"{prefix}: --out {args.out}: not a folder", file=sys.stderr)
        return 2
    try:
        a2l = _a2l(args)
    except A2lError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return exc.code
    try:
        spec = parse_spec(args.bus)
        app = App.open(str(spec), a2l, args.xcp_ids or a2l.ids or xcp_frame_ids(), args.out)
    except BusSpecError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 2
    try:
        server = app.serve(args.listen, args.port)
    except OSError as exc:
        app.close()
        print(f"{prefix}: cannot listen on {args.listen}:{args.port}: {exc.strerror or exc}",
              file=sys.stderr)  # fmt: skip
        return 2
    host = "127.0.0.1" if args.listen in ("0.0.0.0", "::") else args.listen
    url = f"http://{host}:{server.server_address[1]}/?token={app.gsu.token}"
    if args.listen not in ("127.0.0.1", "localhost", "::1"):
        print(f"{prefix}: listening on {args.listen}: the page is open to the network",
              file=sys.stderr)  # fmt: skip
    print(f"{prefix}: {url}", flush=True)
    signal.signal(signal.SIGTERM, _interrupt)  # a stop from a supervisor ends as Ctrl-C does
    try:
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        said = app.close()
        if said is not None:
            print(f"{prefix}: {said}", file=sys.stderr)
    return 0
