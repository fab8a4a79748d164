"""`sil console PORT`: the ECU service port from a terminal, interactive or one command at a time.

PORT is what `sil ecu --serial` serves: the pty path it printed, a serial device or a pyserial
URL. Without an action the interactive screen opens (live values refreshing in place, commands
typed at the bottom); each action runs once and prints its result, as JSON with --json.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING, Any

from ecu.service import live
from protocol import strict_json

if TYPE_CHECKING:
    from sil.console.client import ServiceClient

NAME = "console"
HELP = "talk to the ECU service port: live values, parameters, fault log, arm/throttle/stop"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="the service port: pty path, device or pyserial URL")
    parser.add_argument(
        "--timeout", type=float, default=1.0, metavar="S", help="answer timeout (default 1 s)"
    )
    parser.add_argument(
        "--rate", type=float, default=10.0, metavar="HZ", help="live-data rate (default 10 Hz)"
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--json", action="store_true", help="print the result as JSON")
    actions = parser.add_subparsers(dest="action", metavar="ACTION")
    for name, text in (
        ("identify", "firmware, build, parameter-set CRC, storage"),
        ("counters", "frame and request counters, service time per tick"),
        ("params", "every parameter with its Q format, unit, limits and value"),
        ("save", "store the parameter set in flash"),
        ("faults", "the fault log"),
        ("clear-faults", "clear the fault log"),
        ("arm", "start the engine: arm request (the port becomes the demand source, at idle)"),
        ("stop", "stop request: shut down and cool (held until arm)"),
    ):
        actions.add_parser(name, help=text, parents=[common])
    throttle = actions.add_parser(
        "throttle",
        help="the bench's speed demand, %%N (0: idle); CAN Demand frames win while present",
        parents=[common],
    )
    throttle.add_argument("pct", type=float, metavar="PCT")
    get = actions.add_parser("get", help="read parameters", parents=[common])
    get.add_argument("names", nargs="+", metavar="NAME")
    put = actions.add_parser("set", help="write parameters (unlocks first)", parents=[common])
    put.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    put.add_argument("--save", action="store_true", help="then store the set in flash")
    live = actions.add_parser("live", help="print live samples", parents=[common])
    live.add_argument("--samples", type=int, default=10, metavar="N", help="how many (default 10)")


def _assignment(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name, float(value)
    except ValueError:
        raise ValueError(f"{text!r}: expected NAME=NUMBER") from None


def _do(client: ServiceClient, args: argparse.Namespace) -> Any:
    action = args.action
    if action == "identify":
        return client.identify()
    if action == "counters":
        return client.counters()
    if action == "params":
        return client.params()
    if action == "save":
        return client.save()
    if action == "faults":
        return client.faults()
    if action == "clear-faults":
        return {"cleared": client.clear_faults()}
    if action == "arm":
        return {"mode_before": client.arm()}
    if action == "stop":
        return {"mode_before": client.stop()}
    if action == "throttle":
        return client.throttle(args.pct)
    if action == "get":
        return [client.get(name) for name in args.names]
    if action == "set":
        written = [client.set(name, value) for name, value in map(_assignment, args.assignments)]
        return {"written": written, "saved": client.save() if args.save else None}
    return _live(client, args.rate, args.samples)


def _live(client: ServiceClient, rate: float, count: int) -> list[dict]:
    if count < 1:
        raise ValueError("--samples must be at least 1")
    client.stream(rate)
    client.samples.clear()
    deadline = time.monotonic() + client.timeout_s + count / rate
    while len(client.samples) < count and time.monotonic() < deadline:
        time.sleep(0.005)
        client.receive()
    client.stream(0)
    return [live.decode(raw) for raw in list(client.samples)[:count]]


def _print(result: Any) -> None:
    rows = result if isinstance(result, list) else [result]
    for row in rows:
        print("  ".join(f"{k}={v}" for k, v in row.items()) if isinstance(row, dict) else row)


def run(args: argparse.Namespace) -> int:
    from ecu.service.transport import TransportError, open_transport
    from sil.console import interactive
    from sil.console.client import ServiceClient, ServiceRequestError, ServiceTimeout

    if args.timeout <= 0 or args.rate <= 0:
        print("sil console: --timeout and --rate must be positive", file=sys.stderr)
        return 2
    if args.action is None and not (sys.stdin.isatty() and sys.stdout.isatty()):
        need = "the interactive screen needs a terminal; give an action to run one command"
        print(f"sil console: {need}", file=sys.stderr)
        return 2
    try:
        transport = open_transport(args.port)
    except TransportError as exc:
        print(f"sil console: {exc}", file=sys.stderr)
        return 2
    client = ServiceClient(transport, timeout_s=args.timeout)
    try:
        if args.action is None:
            interactive.run(client, args.rate)
            return 0
        result = _do(client, args)
    except ValueError as exc:
        print(f"sil console: {exc}", file=sys.stderr)
        return 2
    except (ServiceRequestError, ServiceTimeout) as exc:
        print(f"sil console: {exc}", file=sys.stderr)
        return 1
    finally:
        transport.close()
    if args.json:
        print(strict_json.dumps(result, indent=2))
    else:
        _print(result)
    return 0
