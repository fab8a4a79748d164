"""`sil bench TARGET`: speed and memory figures, printed or as JSON."""

from __future__ import annotations

import argparse
import importlib
import json
import sys

NAME = "bench"
HELP = "measure speed and memory figures (codec, plant, ecu, ...)"

# target -> module with `run(quick: bool) -> dict` returning the figures
TARGETS = {
    "codec": "protocol.bench",
    "plant": "plant.bench",
    "ecu": "ecu.bench",
    "replay": "sil.replay_bench",
    "sil": "sil.bench",
    "service": "sil.console.bench",
    "port": "sil.port_bench",
    "realtime": "sil.realtime_bench",
    "pil": "sil.pil_bench",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=sorted(TARGETS), help="what to measure")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--quick", action="store_true", help="shorter run, rougher figures")


def run(args: argparse.Namespace) -> int:
    try:
        figures = importlib.import_module(TARGETS[args.target]).run(quick=args.quick)
    except RuntimeError as exc:  # a bench's own failure (a run without its summary...)
        print(f"sil bench {args.target}: error: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(figures, indent=2))
    else:
        width = max(len(k) for k in figures)
        for key, value in figures.items():
            print(f"{key:<{width}}  {value}")
    return 0
