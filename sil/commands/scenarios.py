"""`sil scenarios`: list the shipped scenarios, or check scenario files."""

from __future__ import annotations

import argparse
import sys

from protocol import strict_json
from sil import scenario

NAME = "scenarios"
HELP = "list the shipped scenarios, or check scenario files (--check FILE...)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--check", nargs="+", metavar="FILE", help="check these scenario files")
    parser.add_argument("--json", action="store_true", help="print as JSON")


def _row(s: scenario.Scenario) -> dict:
    return {
        "name": s.name,
        "plant": s.plant.model,
        "controller": s.controller.kind,
        "duration_s": s.duration_s,
        "faults": len(s.faults),
        "description": s.description,
    }


def run(args: argparse.Namespace) -> int:
    try:
        loaded = [scenario.load(p) for p in (args.check or scenario.shipped_names())]
    except scenario.ScenarioError as exc:
        print(f"sil scenarios: {exc}", file=sys.stderr)
        return 2
    rows = [_row(s) for s in loaded]
    if args.json:
        print(strict_json.dumps(rows, indent=2))
        return 0
    for r in rows:
        print(
            f"{r['name']:<28} {r['plant']:<5} {r['controller']:<9} {r['duration_s']:>6g} s  "
            f"{r['description']}"
        )
    return 0
