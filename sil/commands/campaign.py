"""`sil campaign FILE`: many in-process runs across engine variation, controllers, bus faults and
seeds, on a local process pool or a Dask cluster; a results table and a report."""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
from pathlib import Path

from ecu.port.core import IMPLEMENTATIONS
from protocol import strict_json
from sil import validation
from sil.commands.run import _interrupt_on_signals

NAME = "campaign"
HELP = "run a campaign (engine variation, bus faults, seeds) on a local pool or Dask"
WORKERS_PER_CORE = 4  # --workers at most this many per core: more only thrash
DASK_INSTALL = "pip install 'turbojet-sil[campaign]'"


def max_workers() -> int:
    """The most worker processes --workers may ask for on this machine."""
    return WORKERS_PER_CORE * (os.cpu_count() or 1)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "file", type=validation.input_option, help="campaign file (TOML, see sil/campaign/library/)"
    )
    parser.add_argument(
        "--executor",
        choices=("local", "dask"),
        default="local",
        help="local (default): a process pool on this machine; dask: a Dask cluster",
    )
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="Dask scheduler address (default: a LocalCluster on this machine)",
    )
    parser.add_argument(
        "--ecu-impl",
        choices=IMPLEMENTATIONS,
        default="python",
        help="ECU tick: the Python firmware (default) or its C port (ecu/port)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help=f"worker processes (default: all cores; at most {WORKERS_PER_CORE} per core, "
        f"{max_workers()} here)",
    )
    parser.add_argument(
        "--out", type=validation.path_option, help="output folder (default: out/campaign-NAME)"
    )
    parser.add_argument("--no-report", action="store_true", help="skip report.md and plots")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print the outcome as JSON")


def _finite(x: float) -> float | None:
    """A figure for JSON: NaN (no runs to time) becomes null."""
    return x if math.isfinite(x) else None


def _workers_refusal(workers: int | None) -> str | None:
    """Why ``--workers`` cannot be used, or None."""
    if workers is None or 1 <= workers <= max_workers():
        return None
    return (
        f"--workers: expected a number in 1..{max_workers()} ({WORKERS_PER_CORE} per core on "
        f"{os.cpu_count() or 1} cores), got {workers}"
    )


def _executor_refusal(executor: str) -> str | None:
    """Why ``--executor`` cannot be used here (Dask not importable), or None."""
    if executor != "dask":
        return None
    try:
        import dask.distributed  # noqa: F401
    except ImportError as exc:
        return (
            f"--executor dask needs Dask, which cannot be imported here ({exc}); "
            f"install it with: {DASK_INSTALL}"
        )
    return None


def run(args: argparse.Namespace) -> int:
    from sil.campaign import report
    from sil.campaign.executors import execute
    from sil.campaign.spec import CampaignError, load

    if args.scheduler and args.executor != "dask":
        print("sil campaign: --scheduler needs --executor dask", file=sys.stderr)
        return 2
    refusal = _workers_refusal(args.workers) or _executor_refusal(args.executor)
    if refusal:
        print(f"sil campaign: {refusal}", file=sys.stderr)
        return 2
    try:
        campaign = load(args.file)
    except CampaignError as exc:
        print(f"sil campaign: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("out") / f"campaign-{campaign.name}"
    validation.output_folder("sil campaign", "--out", out)
    out.mkdir(parents=True, exist_ok=True)
    if args.file.resolve() != (out / "campaign.toml").resolve():
        shutil.copyfile(args.file, out / "campaign.toml")
    _interrupt_on_signals()
    try:
        outcome = execute(
            campaign,
            out,
            executor=args.executor,
            ecu_impl=args.ecu_impl,
            workers=args.workers,
            scheduler=args.scheduler,
            progress=not args.no_progress,
        )
    except ValueError as exc:
        print(f"sil campaign: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sil campaign: interrupted; run it again to resume ({out / 'results.csv'})",
              file=sys.stderr)  # fmt: skip
        return 130
    ran = outcome.completed + outcome.failed
    rate = f" ({outcome.runs_per_min:.1f} runs/min)" if ran else ""
    speed = {
        "executor": f"{args.executor}, {args.ecu_impl} ECU",
        "this invocation": f"{ran} runs in {outcome.wall_s:.1f} s{rate}, "
        f"{outcome.skipped} done before",
    }
    summary = {**outcome.__dict__, "runs_per_min": _finite(outcome.runs_per_min), "out": str(out)}
    if not args.no_report:
        summary["report"] = str(report.write(out, campaign.name, speed))
    if args.json:
        print(strict_json.dumps(summary, indent=2, default=float))
    else:
        for key, value in summary.items():
            print(f"{key:<12} {value:.4g}" if isinstance(value, float) else f"{key:<12} {value}")
    return 1 if outcome.failed or outcome.violations else 0
