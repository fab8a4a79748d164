"""`sil schedules [--out DIR]`: the fuel schedules the plant allows, against shaft speed."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from sil.validation import folder_option

NAME = "schedules"
HELP = (
    "fuel schedules from the plant for every engine of a health spread: acceleration line and "
    "schedule (Ndot), steady line and deceleration floor against speed, with margins: CSV, JSON "
    "and a plot"
)


def _fraction(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and 0.0 <= value < 1.0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a fraction in [0, 1)")
    return value


def _speeds(text: str) -> tuple[float, ...]:
    try:
        speeds = tuple(float(s) for s in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list") from None
    if not speeds or not all(math.isfinite(n) and 40.0 <= n <= 105.0 for n in speeds):
        raise argparse.ArgumentTypeError(f"{text!r}: speeds must lie in 40-105 %N")
    return speeds


def _egt(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and 900.0 <= value <= 1500.0):
        raise argparse.ArgumentTypeError(f"{text!r} is not an EGT limit in 900-1500 K")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from plant import schedules as s

    parser.add_argument(
        "--out", type=folder_option, default=Path("out/schedules"), metavar="DIR",
        help="output folder (default out/schedules)",
    )  # fmt: skip
    parser.add_argument(
        "--speeds", type=_speeds, default=s.SPEEDS_PCT, metavar="N,N,...",
        help=f"speeds in %%N (default {s.SPEEDS_PCT[0]:g} to {s.SPEEDS_PCT[-1]:g} by 5)",
    )  # fmt: skip
    parser.add_argument(
        "--egt-limit", type=_egt, default=s.EGT_LIMIT_K, metavar="K",
        help=f"EGT the acceleration line keeps to (default {s.EGT_LIMIT_K:g} K, the ECU's limit)",
    )  # fmt: skip
    parser.add_argument(
        "--surge-margin", type=_fraction, default=s.SURGE_MARGIN, metavar="F",
        help=f"least surge margin on the acceleration line (default {s.SURGE_MARGIN:g})",
    )  # fmt: skip
    parser.add_argument(
        "--lean-margin", type=_fraction, default=s.LEAN_MARGIN, metavar="F",
        help=f"lean blow-out margin of the deceleration floor (default {s.LEAN_MARGIN:g})",
    )  # fmt: skip
    parser.add_argument(
        "--health-spread", type=_fraction, default=s.HEALTH_SPREAD, metavar="F",
        help="the engines to cover: the nominal and every corner of 1 +- F on the compressor's"
        f" and turbine's efficiency and flow (default {s.HEALTH_SPREAD:g}; 0: the nominal alone)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print the table as JSON")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ecu.params import EcuParams
    from plant import schedules as s
    from plant.aerothermal import make_model
    from plant.steady_line import running_line

    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"sil schedules: cannot write to {args.out}: {exc.strerror}", file=sys.stderr)
        return 2
    model = make_model()
    settings = {
        "egt_limit_k": args.egt_limit,
        "surge_margin": args.surge_margin,
        "lean_margin": args.lean_margin,
        "far_lean": model.params.far_lean,
        "health_spread": args.health_spread,
        "keep_accel": s.KEEP_ACCEL,
    }

    tty = sys.stderr.isatty()  # progress on a terminal; a log gets no carriage returns

    def progress(done: int, total: int) -> None:
        print(
            f"\rsil schedules: {done}/{total} engine corners", end="", file=sys.stderr, flush=True
        )

    limits = (args.egt_limit, args.surge_margin, args.lean_margin)
    try:
        corners = s.corner_schedules(
            model, args.speeds, args.health_spread, *limits, progress if tty else None
        )
        points = s.fleet_schedule(model, args.speeds, args.health_spread, *limits, corners=corners)
    except s.ScheduleError as exc:
        print(("\n" if tty else "") + f"sil schedules: {exc}", file=sys.stderr)
        return 1
    if tty:
        print(file=sys.stderr)
    # the EGT at no fuel of each engine's frozen-speed line, at the ECU's pump dead voltage
    dead_v = EcuParams().pump_dead_v
    nominal = s.schedule(model, args.speeds, *limits)
    t0 = [s.zero_fuel_egt_k(p, dead_v) for p in nominal]
    t0 += [s.zero_fuel_egt_k(p, dead_v) for _, own in corners for p in own]
    settings["zero_fuel_egt_k"] = [min(t0), max(t0)]
    if args.speeds[0] <= s.IDLE_PCT < args.speeds[-1]:
        settings["line_rise_s"] = s.line_rise_s(points, running_line(model))
        # each corner on its own acceleration line: what no fleet schedule can beat
        rise = [s.line_rise_s(own, line) if len(own) >= 2 else math.inf for line, own in corners]
        settings["corner_own_line_rise_s"] = [r if math.isfinite(r) else None for r in rise]
        settings["corner_top_pct"] = [own[-1].n_pct if own else None for _, own in corners]
    paths = {"csv": args.out / "schedules.csv", "json": args.out / "schedules.json"}
    s.write_csv(points, paths["csv"])
    s.write_json(points, settings, paths["json"])
    paths["png"] = args.out / "schedules.png"
    s.plot(points, settings, paths["png"])
    if args.json:
        print(paths["json"].read_text(), end="")
        return 0
    print(f"{'N %':>6} {'steady V':>9} {'accel V':>8} {'by':>6} {'SM':>6} {'dN/dt':>7} "
          f"{'decel V':>8} {'dN/dt':>7} {'Ndot max':>9}")  # fmt: skip
    for p in points:
        print(f"{p.n_pct:6.1f} {p.steady_v:9.2f} {p.accel_v:8.2f} {p.accel_limited_by:>6} "
              f"{p.accel_surge_margin:6.1%} {p.accel_rate_pct_s:7.2f} {p.decel_v:8.2f} "
              f"{p.decel_rate_pct_s:7.2f} {p.ndot_pct_s:9.2f}")  # fmt: skip
    if "line_rise_s" in settings:
        print(f"along the acceleration line, the nominal engine from {s.IDLE_PCT:g} %N to 95 % of "
              f"the thrust at {args.speeds[-1]:g} %N: {settings['line_rise_s']:.2f} s at best "
              "(frozen speed, lags neglected)")  # fmt: skip
    if settings.get("corner_own_line_rise_s"):
        rise = np.array(settings["corner_own_line_rise_s"], dtype=float)  # None: nan
        top = np.array(settings["corner_top_pct"], dtype=float)
        print(f"each of the {len(rise)} health corners on its own acceleration line (the best any "
              f"schedule could do for it), to 95 % of the thrust at the highest speed it holds "
              f"within the limits: {np.nanmin(rise):.2f} to {np.nanmax(rise):.2f} s, "
              f"{np.sum(rise <= 5.0)} within 5 s; {np.sum(~(top >= args.speeds[-1]))} hold "
              f"less than {args.speeds[-1]:g} %N")  # fmt: skip
    lo, hi = settings["zero_fuel_egt_k"]
    print(f"EGT at no fuel on the frozen-speed lines (V_d {dead_v:g} V): {lo:.0f} to {hi:.0f} K; "
          f"with egt_zero_fuel_k = {math.floor(lo):g} K the ECU's EGT line puts no engine over the "
          "limit at frozen speed")  # fmt: skip
    for kind, path in paths.items():
        print(f"{kind}: {path}")
    return 0
