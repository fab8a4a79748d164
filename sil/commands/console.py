"""`sil console PORT`: the ECU service port from a terminal, interactive or one command at a time.

PORT is what `sil ecu --serial` serves: the pty path it printed, a serial device or a pyserial
URL. Without an action the interactive screen opens (live values refreshing in place, commands
typed at the bottom); each action runs once and prints its result, as JSON with --json. ``live``
prints each sample as it arrives (with --json a JSON array, one sample a line), and ends early,
keeping what it printed (the array closed), when the ECU stops sending.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING, Any

from ecu.service import live
from ecu.service.port import MIN_STREAM_HZ
from protocol import strict_json
from sil.validation import option

if TYPE_CHECKING:
    from sil.console.client import ServiceClient

NAME = "console"
HELP = (
    "talk to the ECU service port: live values, parameters, fault log, logbook, arm/throttle/stop"
)
MAX_TIMEOUT_S = 3600.0
MAX_RATE_HZ = 1000.0  # the fastest ECU rate; the ECU refuses more than its own


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="the service port: pty path, device or pyserial URL")
    parser.add_argument(
        "--timeout", type=option(positive=True, hi=MAX_TIMEOUT_S), default=1.0, metavar="S",
        help=f"answer timeout, up to {MAX_TIMEOUT_S:g} s (default 1 s)",
    )  # fmt: skip
    parser.add_argument(
        "--rate", type=option(lo=MIN_STREAM_HZ, hi=MAX_RATE_HZ), default=10.0, metavar="HZ",
        help=f"live-data rate, {MIN_STREAM_HZ:g}..{MAX_RATE_HZ:g} Hz up to the ECU's rate "
        "(default 10 Hz)",
    )  # fmt: skip
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
        ("logbook", "the engine's logbook: runs, time in RUN, starts, aborts, last run's peaks"),
        ("arm", "start the engine: arm request (the port becomes the demand source, at idle)"),
        ("stop", "stop request: shut down and cool (held until arm)"),
    ):
        actions.add_parser(name, help=text, parents=[common])
    throttle = actions.add_parser(
        "throttle",
        help="the bench's speed demand, %%N (0: idle); CAN Demand frames win while present",
        parents=[common],
    )
    throttle.add_argument("pct", type=option(), metavar="PCT")
    get = actions.add_parser("get", help="read parameters", parents=[common])
    get.add_argument("names", nargs="+", metavar="NAME")
    put = actions.add_parser("set", help="write parameters (unlocks first)", parents=[common])
    put.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    put.add_argument("--save", action="store_true", help="then store the set in flash")
    live = actions.add_parser("live", help="print live samples", parents=[common])
    live.add_argument(
        "--samples", type=option(integer=True, positive=True), default=10, metavar="N",
        help="how many (default 10)",
    )  # fmt: skip


def _assignment(text: str) -> tuple[str, float]:
    """NAME=NUMBER, a finite number (ValueError naming the parameter)."""
    from sil.console.client import finite_value

    name, sep, value = text.partition("=")
    if not sep or not name:
        raise ValueError(f"set {text!r}: expected NAME=NUMBER")
    return name, finite_value(name, value)


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
    if action == "logbook":
        return client.logbook()
    if action == "arm":
        return {"mode_before": client.arm()}
    if action == "stop":
        return {"mode_before": client.stop()}
    if action == "throttle":
        return client.throttle(args.pct)
    if action == "get":
        return [client.get(name) for name in args.names]
    assignments = [_assignment(text) for text in args.assignments]  # set: all checked first
    for name, value in assignments:
        client.raw_value(name, value)
    written = [client.set(name, value) for name, value in assignments]
    return {"written": written, "saved": client.save() if args.save else None}


def _live(client: ServiceClient, rate: float, count: int, as_json: bool) -> int:
    """Print ``count`` live samples as they arrive; when none comes for the answer timeout and
    two sample periods (the ECU stopped ticking, or went away), end with what was printed: exit
    1 and a line saying how many came."""
    from sil.console.client import ServiceRequestError, ServiceTimeout

    started = client.stream(rate)["rate_hz"]
    client.samples.clear()
    quiet_s = client.timeout_s + 2.0 / started
    got, last = 0, time.monotonic()
    try:
        while got < count and time.monotonic() - last < quiet_s:
            time.sleep(0.005)
            client.receive()
            while client.samples and got < count:
                sample = live.decode(client.samples.popleft())
                opener = "[" if got == 0 else ","
                print(opener + strict_json.dumps(sample) if as_json else _line(sample), flush=True)
                got, last = got + 1, time.monotonic()
    finally:  # (Ctrl-C too: what was printed stays, the stream is stopped)
        if as_json:
            print("]" if got else "[]", flush=True)
        try:
            client.stream(0)
        except (ServiceRequestError, ServiceTimeout):
            pass  # the ECU went away: no stream left to stop
    if got < count:
        print(f"sil console: live: the ECU stopped sending after {got} of {count} samples",
              file=sys.stderr)  # fmt: skip
        return 1
    return 0


def _line(row: dict) -> str:
    return "  ".join(f"{k}={v}" for k, v in row.items())


def _print(result: Any) -> None:
    rows = result if isinstance(result, list) else [result]
    for row in rows:
        print(_line(row) if isinstance(row, dict) else row)


def _print_logbook(rows: list[dict]) -> None:
    for row in rows:
        print(f"{row['name']:<34} {row['value']:>13} {row['unit']}".rstrip())


def run(args: argparse.Namespace) -> int:
    from ecu.service.transport import TransportError, open_transport
    from sil.console import interactive
    from sil.console.client import ServiceClient, ServiceRequestError, ServiceTimeout

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
        if args.action == "live":
            return _live(client, args.rate, args.samples, args.json)
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
    elif args.action == "logbook":
        _print_logbook(result)
    else:
        _print(result)
    return 0
