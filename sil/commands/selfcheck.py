"""`sil selfcheck`: exchange every message of the CAN contract over a bus and check it."""

from __future__ import annotations

import argparse
import sys

from protocol import strict_json
from protocol.bus import BusSpecError, default_spec, parse_spec
from protocol.dbc import ContractError
from protocol.selfcheck import run_selfcheck
from sil.validation import bus_option

NAME = "selfcheck"
HELP = "send every message of the CAN contract over a bus, decode it twice, check E2E"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bus",
        type=bus_option,
        metavar="SPEC",
        help="bus spec (socketcan:vcan0, udp, udp:GROUP@PORT, virtual:NAME, "
        "INTERFACE:CHANNEL); default: vcan0 if up, else loopback multicast",
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")


def run(args: argparse.Namespace) -> int:
    try:
        if args.bus:
            spec = parse_spec(args.bus)
        else:
            spec, why = default_spec()
            if not args.json:
                print(why)
        report = run_selfcheck(spec)
    except (BusSpecError, ContractError, TimeoutError) as exc:
        print(f"sil selfcheck: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(strict_json.dumps(report.as_dict(), indent=2))
        return 0 if report.ok else 1
    print(f"{'message':<14} {'id':>5}  {'e2e':<6} {'codec=cantools=sent':<20} values")
    for row in report.rows:
        values = ", ".join(f"{k}={v:g}" for k, v in row.sent.items())
        print(
            f"{row.message:<14} 0x{row.frame_id:03X}  {row.e2e:<6} "
            f"{'yes' if row.ok else 'NO':<20} {values}"
        )
    print("E2E checker: " + ", ".join(f"{k} -> {v}" for k, v in report.e2e_cases.items()))
    print(f"median send-to-receive time: {report.round_trip_us:.0f} us")
    print("self-check " + ("passed" if report.ok else "FAILED"))
    return 0 if report.ok else 1
