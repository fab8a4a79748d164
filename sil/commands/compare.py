"""`sil compare RUN_A RUN_B`: two runs side by side (for example PID against MRAC)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from protocol import strict_json
from sil import validation
from sil.analysis.metrics import load_trace  # noqa: E402
from sil.record import results  # noqa: E402
from sil.run import run_folder

NAME = "compare"
HELP = "compare two runs: table of their summaries and an overlay plot of speed"
FIELDS = (
    "status",
    "sim_time_s",
    "realtime_factor",
    "tracking_rms_pct",
    "tracking_speed_loop_rms_pct",
    "max_egt_K",
    "egt_limit_time_s",
    "missed_ticks",
    "bus_load_pct",
)


EPILOG = """exit status:
  0  both runs completed; table and plot written
  1  --allow-incomplete: compared, but a run did not complete (marked INCOMPLETE)
  2  refused: a folder without a readable summary.json and trace.csv, a run whose status is not
     "completed" (unless --allow-incomplete), or bad arguments"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("run_a", type=validation.path_option, help="output folder of the first run")
    parser.add_argument(
        "run_b", type=validation.path_option, help="output folder of the second run"
    )
    parser.add_argument("--out", metavar="DIR", help="folder for compare.png (default: RUN_B)")
    parser.add_argument(
        "--allow-incomplete",
        action="store_true",
        help="compare what an aborted run recorded, marked INCOMPLETE (exit 1), instead of "
        "refusing it",
    )
    parser.add_argument("--json", action="store_true", help="print the table as JSON")


TRACE_COLUMNS = ("time", "command", "ReferenceSpeed", "speed_true")  # what the plot draws


def _fmt(value: object) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _load(run: Path, allow_incomplete: bool) -> tuple[dict, dict, str | None]:
    """The run's summary, trace and why it is incomplete (None: completed). Raises
    :class:`~sil.record.results.IncompleteRun` for a folder it cannot compare."""
    summary = results.load_summary(run)
    why = results.incomplete_reason(summary)
    if why is not None and not allow_incomplete:
        raise results.IncompleteRun(
            f"{run}: incomplete run ({why}); --allow-incomplete compares what it recorded"
        )
    if not (run / "trace.csv").is_file():
        raise results.IncompleteRun(f"{run}: no trace.csv" + (f" ({why})" if why else ""))
    try:
        trace = load_trace(run / "trace.csv")
    except (OSError, ValueError) as exc:
        raise results.IncompleteRun(f"{run / 'trace.csv'}: cannot be read: {exc}") from None
    missing = [c for c in TRACE_COLUMNS if c not in trace]
    if missing:
        raise results.IncompleteRun(f"{run / 'trace.csv'}: no column {', '.join(missing)}")
    return summary, trace, why


def run(args: argparse.Namespace) -> int:
    allow = getattr(args, "allow_incomplete", False)
    try:
        (sa, ta, why_a), (sb, tb, why_b) = _load(args.run_a, allow), _load(args.run_b, allow)
    except results.IncompleteRun as exc:
        print(f"sil compare: {exc}", file=sys.stderr)
        return 2
    try:
        out = run_folder.out_path("--out", args.out) or args.run_b
        run_folder.check("--out", out)
        lock = run_folder.FolderLock(out)
    except run_folder.FolderError as exc:
        print(f"sil compare: {exc}", file=sys.stderr)
        return 2
    for run_dir, why in ((args.run_a, why_a), (args.run_b, why_b)):
        if why is not None:
            print(f"sil compare: {run_dir}: INCOMPLETE run ({why})", file=sys.stderr)
    code = 0 if why_a is None and why_b is None else 1
    names = (_name(sa, args.run_a, why_a), _name(sb, args.run_b, why_b))
    rows = [{"field": f, "a": sa.get(f), "b": sb.get(f)} for f in FIELDS]
    try:
        with lock:
            _plot(ta, tb, names, out / "compare.png")
    except results.WriteError as exc:
        print(f"sil compare: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(
            strict_json.dumps(
                {
                    "a": names[0],
                    "b": names[1],
                    "incomplete": {"a": why_a, "b": why_b},
                    "rows": rows,
                    "plot": str(out / "compare.png"),
                },
                indent=2,
            )
        )
        return code
    key = max(len(f) for f in FIELDS)
    print(f"{'':<{key}} {names[0]:>28} {names[1]:>28}")
    for r in rows:
        print(f"{r['field']:<{key}} {_fmt(r['a']):>28} {_fmt(r['b']):>28}")
    print(f"plot: {out / 'compare.png'}")
    return code


def _plot(ta: dict, tb: dict, names: tuple[str, str], path: Path) -> None:
    """The overlay of speed, written atomically as ``path`` (WriteError names it)."""
    fig, ax = plt.subplots(figsize=(10, 5))
    ax.plot(ta["time"], ta["command"], color="0.6", lw=1, label="command")
    ax.plot(
        ta["time"], ta["ReferenceSpeed"], "--", color="tab:green", lw=1, label="reference model"
    )
    ax.plot(ta["time"], ta["speed_true"], lw=1.2, label=names[0])
    ax.plot(tb["time"], tb["speed_true"], lw=1.2, label=names[1])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("shaft speed [%N_max]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        results.write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        plt.close(fig)


def _name(summary: dict, run: Path, why: str | None) -> str:
    name = str(summary.get("scenario", run))
    return name if why is None else f"{name} (INCOMPLETE)"
