"""`sil steady-line [--out DIR]`: the aero-thermal engine's running line as CSV and PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from sil.validation import folder_option

NAME = "steady-line"
HELP = (
    "running line over the fuel range: CSV and PNG of P3, EGT, fuel and thrust vs speed, and the "
    "fuel-staircase transients"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        type=folder_option,
        default=Path("out/steady_line"),
        metavar="DIR",
        help="output folder (default out/steady_line)",
    )


def run(args: argparse.Namespace) -> int:
    from plant import staircase
    from plant.aerothermal import make_model
    from plant.steady_line import plot, running_line, write_csv
    from plant.trim import solve_steady

    args.out.mkdir(parents=True, exist_ok=True)
    model = make_model()
    table = running_line(model)
    csv_path, png_path = args.out / "steady_line.csv", args.out / "steady_line.png"
    write_csv(table, csv_path)
    plot(table, png_path)
    fuels = [staircase.steady_fuel_for(table, n) for n in staircase.LEVELS_PCT]
    t, x, u = staircase.run(model, solve_steady(model, 0.008).x, fuels, 8.0, pump_in_loop=False)
    stairs_path = args.out / "staircase.png"
    staircase.plot(t, x, u, str(stairs_path))
    n = table["N_pct"]
    print(f"running line: {len(n)} points, {n.min():.1f} to {n.max():.1f} %N")
    print(f"wrote {csv_path}, {png_path} and {stairs_path}")
    return 0
