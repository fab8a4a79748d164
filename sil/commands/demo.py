"""`sil demo`: MRAC against PID on the 70-100 %N staircase, on the default bus, with plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sil.commands import compare
from sil.commands import run as run_command
from sil.run import run_folder

NAME = "demo"
HELP = "run the demo: MRAC and PID on the staircase over the default bus, compared, with plots"
SCENARIOS = (("mrac", "thesis-5.4-staircase"), ("pid", "thesis-6.2-staircase-pid"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_command.add_run_options(parser, out_default="out/demo, a folder per controller inside")
    parser.set_defaults(out=str(Path("out") / "demo"))


def run(args: argparse.Namespace) -> int:
    try:
        out = run_folder.out_path("--out", args.out)
        assert out is not None
        run_folder.check("--out", out)
    except run_folder.FolderError as exc:
        print(f"sil demo: {exc}", file=sys.stderr)
        return 2
    worst = 0
    for label, name in SCENARIOS:
        print(f"== {name} ({label})", flush=True)
        worst = max(worst, run_command.execute(name, args, out=out / label))
    if worst == 0:
        print("== comparison", flush=True)
        worst = compare.run(
            argparse.Namespace(run_a=out / "mrac", run_b=out / "pid", out=str(out), json=False)
        )
    return worst
