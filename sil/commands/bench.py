"""`sil bench TARGET`: speed and memory figures, printed or as JSON; `sil bench all`: every
bench, and the page docs/benchmarks.md (sil/bench/suite.py)."""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from protocol import strict_json
from sil.bench import TARGETS

NAME = "bench"
HELP = "measure speed and memory figures (codec, plant, ecu, ...)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "target",
        choices=[*sorted(TARGETS), "all"],
        help="what to measure; all: every bench in turn (quick unless --full)",
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--quick", action="store_true", help="shorter run, rougher figures")
    parser.add_argument("--full", action="store_true", help="all: the full runs, not quick ones")
    parser.add_argument(
        "--against",
        metavar="REV",
        help="ecu: time the firmware tick of git revision REV in the same run too, alternating "
        "with this one, and give the speed-up (after checking both give the same outputs)",
    )
    parser.add_argument(
        "--only",
        metavar="A,B",
        help="all: these benches only (comma-separated names)",
    )
    parser.add_argument(
        "--markdown",
        type=Path,
        metavar="FILE",
        help="all: write the page of figures (machine, targets, each bench) to FILE, "
        "e.g. docs/benchmarks.md",
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="all, with --markdown: write the benches run now into the page FILE already holds, "
        "keeping the others as they were measured",
    )


def run(args: argparse.Namespace) -> int:
    if args.target == "all":
        return _run_all(args)
    if args.only or args.markdown or args.full or args.merge:
        print("sil bench: --only, --markdown, --merge and --full go with 'all'", file=sys.stderr)
        return 2
    if args.against is not None and args.target != "ecu":
        print("sil bench: --against goes with 'ecu'", file=sys.stderr)
        return 2
    options = {"against": args.against} if args.against is not None else {}
    try:
        figures = importlib.import_module(TARGETS[args.target]).run(quick=args.quick, **options)
    except ValueError as exc:  # input the bench refuses (a revision git does not know)
        print(f"sil bench {args.target}: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a bench's own failure (a run without its summary...)
        print(f"sil bench {args.target}: error: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(strict_json.dumps(figures, indent=2))
    else:
        width = max(len(k) for k in figures)
        for key, value in figures.items():
            print(f"{key:<{width}}  {value}")
    return 0


def _run_all(args: argparse.Namespace) -> int:
    from sil.bench.suite import markdown, merge, print_progress, run_all

    names = list(TARGETS) if not args.only else [n.strip() for n in args.only.split(",")]
    unknown = [n for n in names if n not in TARGETS]
    if unknown or not names:
        print(
            f"sil bench all: --only: unknown bench {', '.join(unknown) or '(none given)'} "
            f"(known: {', '.join(TARGETS)})",
            file=sys.stderr,
        )
        return 2
    if args.markdown is not None and not args.markdown.parent.is_dir():
        print(f"sil bench all: --markdown {args.markdown}: no such folder", file=sys.stderr)
        return 2
    if args.merge and (args.markdown is None or not args.markdown.is_file()):
        print("sil bench all: --merge needs --markdown FILE of a page already written",
              file=sys.stderr)  # fmt: skip
        return 2
    result = run_all({n: TARGETS[n] for n in names}, quick=not args.full, progress=print_progress)
    if args.markdown is not None:
        page = merge(args.markdown.read_text(), result) if args.merge else markdown(result)
        args.markdown.write_text(page)
        print(f"sil bench all: wrote {args.markdown}", file=sys.stderr)
    if args.json:
        print(strict_json.dumps(result, indent=2))
    else:
        for name, entry in result["benches"].items():
            if "error" in entry:
                print(f"{name:<10}  FAILED: {entry['error']}")
                continue
            met = entry["targets_met"]
            verdict = (
                ", ".join(f"{t} {'met' if ok else 'NOT met'}" for t, ok in met.items())
                or "no target"
            )
            print(f"{name:<10}  {entry['seconds']:6.1f} s  {verdict}")
    return 1 if any("error" in e for e in result["benches"].values()) else 0
