"""`sil trim --fuel KG_S [--json]`: the steady state of the aero-thermal engine at a fuel flow."""

from __future__ import annotations

import argparse
import json
import sys

NAME = "trim"
HELP = "steady state (P3, P5, T4, N, EGT, thrust, air flow) of the engine at a fuel flow"

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

    try:
        ambient = Ambient(t0_k=args.t0, p0_pa=args.p0, flight_speed_m_s=args.flight_speed)
        summary = trim_summary(make_model(ambient), args.fuel)
    except (ValueError, RuntimeError) as exc:
        print(f"sil trim: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            print(f"{key:<10} {value:>14.6g} {_UNITS[key]}")
    return 0
