"""`sil demo`: MRAC against PID on the 70-100 %N staircase, on the default bus, with plots."""

from __future__ import annotations

import argparse
from pathlib import Path

from sil.commands import compare
from sil.commands import run as run_command

NAME = "demo"
HELP = "run the demo: MRAC and PID on the staircase over the default bus, compared, with plots"
SCENARIOS = (("mrac", "thesis-5.4-staircase"), ("pid", "thesis-6.2-staircase-pid"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_command.add_run_options(parser, out_default="out/demo, a folder per controller inside")
    parser.set_defaults(out=Path("out") / "demo")


def run(args: argparse.Namespace) -> int:
    worst = 0
    for label, name in SCENARIOS:
        print(f"== {name} ({label})", flush=True)
        worst = max(worst, run_command.execute(name, args, out=args.out / label))
    if worst == 0:
        print("== comparison", flush=True)
        worst = compare.run(
            argparse.Namespace(
                run_a=args.out / "mrac", run_b=args.out / "pid", out=args.out, json=False
            )
        )
    return worst
