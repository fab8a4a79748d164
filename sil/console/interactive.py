"""The interactive service terminal: live values refreshing in place and a command line.

The screen (curses) is a thin loop around two plain functions that tests call directly:
:func:`render` turns the newest live sample into lines, :func:`execute` runs one typed command
against a :class:`sil.console.client.ServiceClient` and returns the lines to show.
"""

from __future__ import annotations

import curses
import shlex

from ecu import faults as F
from ecu import start_sequencer as Q
from ecu.modes import NAMES as MODE_NAMES
from ecu.service.bench_demand import SOURCE_NAMES
from sil.console.client import ServiceClient, ServiceRequestError, ServiceTimeout, finite_value

HELP = (
    "arm | throttle PCT | stop | get NAME | set NAME VALUE | params | save | faults | clear | "
    "logbook | rate HZ | counters | help | quit"
)


def render(ident: dict, sample: dict[str, int | float] | None, stream_gaps: int) -> list[str]:
    head = (
        f"{ident['firmware']}  build {ident['build']}  protocol {ident['protocol']}  "
        f"param CRC 0x{ident['param_crc']:04X}  storage {ident['storage']}"
    )
    if sample is None:
        return [head, "", "waiting for live data..."]
    v = sample
    faults = ", ".join(F.names(int(v["fault_word"]))) or "none"
    if v["inputs_valid"]:
        speed = f"speed {v['speed']:7.2f} %N  ({v['speed_rpm']:.0f} rpm)"
        egt = f"EGT {v['egt']:7.1f} K"
    else:
        speed, egt = "speed  (no valid reading yet)", "EGT (no valid reading yet)"
    return [
        head,
        "",
        f"mode {MODE_NAMES[int(v['mode'])]:<9} tick {int(v['tick']):>9}   "
        f"lost samples {stream_gaps}",
        f"demand {v['demand']:6.2f} %N from {SOURCE_NAMES[int(v['demand_source'])]:<5}   "
        f"{speed}   reference {v['speed_ref']:7.2f} %N",
        start_line(v),
        f"{egt}   pump {v['pump_voltage']:6.3f} V  duty {v['pump_duty']:6.2f} %  "
        f"enable {int(v['pump_enable'])}",
        f"supply {v['supply']:6.3f} V   pump current {v['pump_current']:6.3f} A   "
        f"pump health {v['pump_health']:6.1f} %",
        f"A_p row 2 {v['ap21']:9.4f} {v['ap22']:9.4f}   Lambda {v['lambda']:8.4f}   "
        f"Theta_f {v['theta21']:9.5f} {v['theta22']:9.5f}",
        f"K_x {v['kx1']:9.4f} {v['kx2']:9.4f}   K_r {v['kr']:8.4f}   "
        f"K_f {v['kf1']:9.5f} {v['kf2']:9.5f}",
        f"faults: {faults}",
    ]


def start_line(v: dict[str, int | float]) -> str:
    """The sequencer's step and time in it, starter, igniter, EGT against the start's target
    and limit, and the last start's abort reason."""
    return (
        f"start step {Q.NAMES[int(v['seq_state'])]:<10} {v['seq_time']:6.1f} s   "
        f"starter {v['starter']:5.1f} %  igniter {'on ' if v['igniter'] else 'off'}   "
        f"EGT target {v['egt_start_target']:.0f} K, limit {v['egt_start_limit']:.0f} K   "
        f"last abort {Q.REASONS[int(v['seq_reason'])]}"
    )


def execute(client: ServiceClient, line: str) -> list[str]:
    """Run one command; returns the lines to show (errors included, never raised)."""
    try:
        words = shlex.split(line)
    except ValueError as exc:
        return [f"error: {exc}"]
    if not words:
        return []
    cmd, args = words[0], words[1:]
    try:
        return _command(client, cmd, args)
    except (ServiceRequestError, ServiceTimeout, ValueError) as exc:
        return [f"error: {exc}"]


def _command(client: ServiceClient, cmd: str, args: list[str]) -> list[str]:
    if cmd == "get" and len(args) == 1:
        r = client.get(args[0])
        return [f"{r['name']} = {r['value']:g} (raw {r['raw']}, Q frac {r['frac']})"]
    if cmd == "set" and len(args) == 2:
        r = client.set(args[0], finite_value(args[0], args[1]))
        return [
            f"{r['name']} = {r['value']:g} (param CRC 0x{r['param_crc']:04X}; 'save' stores it)"
        ]
    if cmd == "params" and not args:
        return [
            f"{p['name']:<20} {p['value']:>12g} {p['unit']:<9} Q{31 - p['frac']}.{p['frac']:<3}"
            f"[{p['min']:g}, {p['max']:g}]"
            f"{'' if p['run_safe'] else '  (not in RUN)'}"
            for p in client.params()
        ]
    if cmd == "save" and not args:
        r = client.save()
        return [f"saved to slot {r['slot']}, sequence {r['sequence']}"]
    if cmd == "faults" and not args:
        entries = client.faults()
        return [
            f"{e['time_s']:10.2f} s  {e['name']:<18} "
            + " ".join(f"{k}={v}" for k, v in e["snapshot"].items())
            + (f"  (x{e['count']}, last {e['last_s']:.2f} s)" if e["count"] > 1 else "")
            for e in entries
        ] or ["fault log empty"]
    if cmd == "logbook" and not args:
        return [f"{r['name']:<24} {r['value']:>12} {r['unit']}".rstrip() for r in client.logbook()]
    if cmd == "clear" and not args:
        return [f"cleared {client.clear_faults()} entries"]
    if cmd == "arm" and not args:
        return [f"arm requested (mode was {client.arm()})"]
    if cmd == "stop" and not args:
        return [f"stop requested (mode was {client.stop()})"]
    if cmd == "throttle" and len(args) == 1:
        try:
            pct = float(args[0])
        except ValueError:
            return [f"error: throttle {args[0]!r} is not a number"]
        r = client.throttle(pct)
        return [f"demand {r['demand_pct']:g} %N from {r['source']}"]
    if cmd == "rate" and len(args) == 1:
        try:
            rate = float(args[0])
        except ValueError:
            return [f"error: rate {args[0]!r} is not a number"]
        return [f"streaming at {client.stream(rate)['rate_hz']:g} Hz"]
    if cmd == "counters" and not args:
        return [" ".join(f"{k}={v}" for k, v in client.counters().items())]
    return [f"commands: {HELP}"]


def run(client: ServiceClient, rate_hz: float) -> None:
    """The curses screen until 'quit' or Ctrl-C."""
    ident = client.identify()
    client.stream(rate_hz)
    try:
        curses.wrapper(_loop, client, ident)
    finally:
        client.stream(0)


def _loop(screen: curses.window, client: ServiceClient, ident: dict) -> None:
    curses.curs_set(1)
    screen.timeout(100)
    typed = ""
    output: list[str] = [f"commands: {HELP}"]
    while True:
        client.receive()
        height, width = screen.getmaxyx()
        screen.erase()
        lines = render(ident, client.latest(), client.stream_gaps) + [""] + output
        for row, text in enumerate(lines[: height - 2]):
            screen.addnstr(row, 0, text, width - 1)
        screen.addnstr(height - 1, 0, "> " + typed, width - 1)
        screen.refresh()
        try:
            key = screen.get_wch()  # waits at most the screen's 100 ms timeout
        except curses.error:
            continue
        if key in ("\n", "\r", curses.KEY_ENTER):
            if typed.strip() in ("quit", "exit"):
                return
            output = execute(client, typed)
            if typed.strip().startswith(("set", "save")):
                ident = client.identify()
            typed = ""
        elif key in (curses.KEY_BACKSPACE, "\x7f", "\b"):
            typed = typed[:-1]
        elif isinstance(key, str) and key.isprintable():
            typed += key
