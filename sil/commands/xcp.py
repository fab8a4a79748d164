"""`sil xcp record`: DAQ from the ECU's XCP slave, pyXCP the master, into an MF4 with the A2L's
names, units and conversions (sil/record/xcp_record.py; docs/calibration.md)."""

from __future__ import annotations

import argparse
import socket
import sys

from protocol import strict_json
from sil import validation
from sil.validation import option

SO_RCVBUFFORCE = 33  # <asm-generic/socket.h>
NAME = "xcp"
HELP = "an XCP master on the ECU: record DAQ into an MF4 with the A2L's names and units"
RECORD = (
    "record measurements of the A2L by DAQ on an event of the ECU (pyXCP the master) into an "
    "MF4: a channel per measurement, its A2L name, unit and conversion"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = actions.add_parser("record", help=RECORD, description=RECORD)
    p.add_argument("--bus", type=validation.bus_option, metavar="SPEC",
                   help="the ECU's bus (default as in protocol)")  # fmt: skip
    p.add_argument("--a2l", type=validation.path_option, required=True, metavar="FILE",
                   help="the ECU's A2L (sil a2l): addresses, types, units, XCP IDs")  # fmt: skip
    p.add_argument("--measure", nargs="+", action="extend", required=True, metavar="NAME",
                   help="MEASUREMENTs of the A2L to record (repeatable)")  # fmt: skip
    p.add_argument("--seconds", type=option(lo=0.01, hi=1e6), required=True, metavar="S",
                   help="how long to record (wall-clock time)")  # fmt: skip
    p.add_argument("--out", type=validation.path_option, required=True, metavar="FILE.mf4",
                   help="the MF4 to write")  # fmt: skip
    p.add_argument("--event", type=option(integer=True, lo=0, hi=255), default=0, metavar="N",
                   help="the DAQ event: 0 the control tick (default), 1 every 100 ms")  # fmt: skip
    p.add_argument("--prescaler", type=option(integer=True, lo=1, hi=255), default=1,
                   metavar="N", help="a sample every N events (default 1)")  # fmt: skip
    p.add_argument("--connect-timeout", type=option(lo=0.1, hi=3600), default=10.0,
                   metavar="S", help="wait for the slave to answer (default 10 s)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print what was recorded as JSON")


def _room_for_bursts(bus) -> None:  # noqa: ANN001 (a python-can bus)
    """DAQ from a lockstep run comes in bursts far beyond a CAN bus's rate: the loopback bus's
    socket gets room for them (beyond the system's limit where allowed, as root)."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return
    for name in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
        try:
            sock.setsockopt(socket.SOL_SOCKET, name, 64 << 20)
            return
        except OSError:
            continue


def run(args: argparse.Namespace) -> int:
    from protocol.bus import BusSpecError, default_spec, open_bus, parse_spec
    from sil.record import xcp_record
    from sil.record.a2l import A2lError, read_a2l
    from sil.record.mdf import MdfUnavailable, asammdf
    from sil.record.results import WriteError

    prefix = "sil xcp record"
    try:
        asammdf()
        a2l = read_a2l(args.a2l)
        measurements = xcp_record.pick(a2l, args.measure)
    except (A2lError, MdfUnavailable) as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 2
    if args.out.is_dir() or not args.out.parent.is_dir():
        print(f"{prefix}: --out {args.out}: not a file in an existing folder", file=sys.stderr)
        return 2
    try:
        if args.bus:
            spec = parse_spec(args.bus)
        else:
            spec, why = default_spec()
            print(why, file=sys.stderr)
        bus = open_bus(spec)
    except BusSpecError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 2
    _room_for_bursts(bus)
    try:
        recording = xcp_record.record(
            bus,
            a2l,
            measurements,
            args.seconds,
            event=args.event,
            prescaler=args.prescaler,
            connect_timeout_s=args.connect_timeout,
        )
        xcp_record.write(args.out, recording, a2l, args.a2l, args.event)
    except xcp_record.RecordError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return exc.code
    except WriteError as exc:
        print(f"{prefix}: {exc}", file=sys.stderr)
        return 1
    finally:
        bus.shutdown()
    done = xcp_record.summary(recording, args.out, args.event)
    for note in recording.notes:
        print(f"{prefix}: note: {note}", file=sys.stderr)
    if args.json:
        print(strict_json.dumps(done, indent=2))
    else:
        print(
            f"{prefix}: {args.out}: {done['samples']:,} samples of {len(measurements)} "
            f"measurements on event {args.event} over {done['seconds']:.3f} s, start "
            f"{done['start']}",
            file=sys.stderr,
        )
    return 0
