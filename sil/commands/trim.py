"""`sil trim --fuel KG_S [--json]`: the steady state of the aero-thermal engine at a fuel flow."""

from __future__ import annotations

import argparse
import math
import sys

from protocol import strict_json
from sil import validation

NAME = "trim"
HELP = "steady state (P3, P5, T4, N, EGT, thrust, air flow) of the engine at a fuel flow"

MAX_FUEL_AIR = 0.068  # stoichiometric kerosene: no steady state burns more fuel per air
MAX_N_PCT = 110.0  # the ECU's overspeed ceiling (ecu.params)

_UNITS = {
    "fuel_kg_s": "kg/s",
    "P3_Pa": "Pa",
    "P5_Pa": "Pa",
    "T4_K": "K",
    "N_pct": "%",
    "N_rpm": "rpm",
    "EGT_K": "K",
    "thrust_N": "N",
    "air_kg_s": "kg/s",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fuel",
        type=float,
        default=0.008,
        metavar="KG_S",
        help="fuel flow in kg/s (default 0.008, the document's trim, eq. 2.33)",
    )
    parser.add_argument("--t0", type=float, default=288.15, metavar="K", help="ambient temperature")
    parser.add_argument("--p0", type=float, default=101325.0, metavar="PA", help="ambient pressure")
    parser.add_argument(
        "--flight-speed",
        type=float,
        default=0.0,
        metavar="M_S",
        help="flight speed (default 0: test bench)",
    )
    parser.add_argument("--json", action="store_true", help="print the state as JSON")


def run(args: argparse.Namespace) -> int:
    from plant.aerothermal import make_model
    from plant.interface import Ambient
    from plant.trim import trim_summary

    source = "sil trim"
    validation.number(source, "--fuel (fuel flow, kg/s)", args.fuel, positive=True)
    validation.number(source, "--t0", args.t0, lo=200, hi=350)
    validation.number(source, "--p0", args.p0, lo=20_000, hi=110_000)
    validation.number(source, "--flight-speed", args.flight_speed, lo=0, hi=300)
    try:
        ambient = Ambient(t0_k=args.t0, p0_pa=args.p0, flight_speed_m_s=args.flight_speed)
        summary = trim_summary(make_model(ambient), args.fuel)
    except (ValueError, RuntimeError, FloatingPointError) as exc:  # (no state, or none finite)
        print(f"sil trim: --fuel {args.fuel:g}: no steady state: {exc}", file=sys.stderr)
        return 2
    far = summary["fuel_kg_s"] / summary["air_kg_s"] if summary["air_kg_s"] > 0 else math.inf
    n = summary["N_pct"]
    if not (math.isfinite(far) and 0 < far <= MAX_FUEL_AIR and 0 < n <= MAX_N_PCT):
        print(
            f"sil trim: --fuel {args.fuel:g}: outside the model's envelope (fuel-air ratio "
            f"{far:.3g}, N {n:.4g} %; the maps hold fuel-air ratios up to {MAX_FUEL_AIR} and "
            f"speeds up to {MAX_N_PCT} %N)",
            file=sys.stderr,
        )
        return 2
    if args.json:
        print(strict_json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            print(f"{key:<10} {value:>14.6g} {_UNITS[key]}")
    return 0
