"""`sil compare RUN_A RUN_B`: two runs side by side (for example PID against MRAC)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sil.metrics import load_trace  # noqa: E402

NAME = "compare"
HELP = "compare two runs: table of their summaries and an overlay plot of speed"
FIELDS = (
    "status",
    "sim_time_s",
    "realtime_factor",
    "tracking_rms_pct",
    "max_egt_K",
    "egt_limit_time_s",
    "missed_ticks",
    "bus_load_pct",
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_a", type=Path, help="output folder of the first run")
    parser.add_argument("run_b", type=Path, help="output folder of the second run")
    parser.add_argument("--out", type=Path, help="folder for compare.png (default: RUN_B)")
    parser.add_argument("--json", action="store_true", help="print the table as JSON")


def _fmt(value: object) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _load(run: Path) -> tuple[dict, dict]:
    for name in ("summary.json", "trace.csv"):
        if not (run / name).is_file():
            raise FileNotFoundError(f"{run}: no {name} (is this the output folder of a run?)")
    try:
        summary = json.loads((run / "summary.json").read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{run / 'summary.json'}: not valid JSON: {exc}") from None
    return summary, load_trace(run / "trace.csv")


def run(args: argparse.Namespace) -> int:
    try:
        (sa, ta), (sb, tb) = _load(args.run_a), _load(args.run_b)
    except (FileNotFoundError, ValueError) as exc:
        print(f"sil compare: {exc}", file=sys.stderr)
        return 2
    names = (sa.get("scenario", str(args.run_a)), sb.get("scenario", str(args.run_b)))
    rows = [{"field": f, "a": sa.get(f), "b": sb.get(f)} for f in FIELDS]
    out = args.out or args.run_b
    out.mkdir(parents=True, exist_ok=True)
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
    fig.savefig(out / "compare.png", dpi=110)
    plt.close(fig)
    if args.json:
        print(
            json.dumps(
                {"a": names[0], "b": names[1], "rows": rows, "plot": str(out / "compare.png")},
                indent=2,
            )
        )
        return 0
    print(f"{'':<18} {names[0]:>28} {names[1]:>28}")
    for r in rows:
        print(f"{r['field']:<18} {_fmt(r['a']):>28} {_fmt(r['b']):>28}")
    print(f"plot: {out / 'compare.png'}")
    return 0
