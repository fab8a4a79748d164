"""`sil identify FILE`: fit the fast engine model (ch. 3) to a recording, report and export it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from protocol import strict_json
from sil import validation  # noqa: E402
from sil.analysis import identify as ident  # noqa: E402
from sil.record.canlog import LogReadError  # noqa: E402

NAME = "identify"
HELP = "identify the fast engine model (eq. 3.5 or appendix B) from a trace, CAN log or CSV"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "file", type=validation.input_option, help="trace.csv of a run, a CAN log, or a plain CSV"
    )
    parser.add_argument(
        "--order",
        choices=ident.ORDERS,
        default="second",
        help="model: eq. 3.5 (second, default), eq. 3.1 (second-linear), eq. B.4 (first), "
        "appendix B's linear first order (first-linear), B.4 + dN^2 dV (first-quadratic)",
    )
    parser.add_argument(
        "--trim-n", type=validation.option(), metavar="PCT", help="trim speed, %%N_max"
    )
    parser.add_argument(
        "--trim-v", type=validation.option(), metavar="VOLTS", help="trim pump voltage"
    )
    parser.add_argument(
        "--window",
        type=int,
        metavar="SAMPLES",
        help="Savitzky-Golay window (odd; default: chosen by fit)",
    )
    parser.add_argument(
        "--validate",
        type=validation.input_option,
        metavar="FILE",
        help="a second recording to judge the fit on (default: held-out part)",
    )
    parser.add_argument(
        "--holdout",
        type=float,
        default=0.3,
        help="fraction at the end kept out of the fit (default 0.3)",
    )
    parser.add_argument("--time-column", default="time")
    parser.add_argument("--speed-column", default="speed_meas")
    parser.add_argument("--voltage-column", default="PumpVoltageTarget")
    parser.add_argument("--speed-unit", choices=("pct", "rpm"), default="pct")
    parser.add_argument(
        "--out", type=validation.path_option, help="folder for identify.json and the fit plot"
    )
    parser.add_argument(
        "--export",
        type=validation.path_option,
        metavar="FILE",
        help="write the ECU commissioning file (initial estimates, trim); a file the ECU would "
        "refuse is not written (exit 2)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="export a fit that is not trusted (see below) instead of exiting 1",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    low, high = ident.running_range()
    parser.epilog = (
        f"A fit is not trusted, and nothing is exported (exit 1, unless --force), when its NRMSE "
        f"on the validation data is above {ident.MAX_NRMSE_PCT:g} %, or its trim point or any "
        f"sample lies outside the running range {low:g}..{high:g} %N (from the ECU's start "
        f"hand-over speed to its overspeed limit)."
    )


def _plot(path: Path, rec: ident.Recording, simulated: np.ndarray, title: str) -> None:
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]}
    )
    ax.plot(rec.t, rec.n_pct, lw=1, label="recorded")
    ax.plot(rec.t, simulated, "--", lw=1.2, label="identified model")
    ax.set_ylabel("shaft speed [%N_max]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax2.plot(rec.t, rec.v, color="tab:red", lw=1)
    ax2.set_ylabel("pump [V]")
    ax2.set_xlabel("time [s]")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    columns = {
        "time_column": args.time_column,
        "speed_column": args.speed_column,
        "voltage_column": args.voltage_column,
        "speed_unit": args.speed_unit,
    }
    if args.out:
        validation.output_folder("sil identify", "--out", args.out)
    if args.export:
        validation.output_file("sil identify", "--export", args.export)
    try:
        rec = ident.read_recording(args.file, **columns)
        if args.validate:
            fit_part, check = rec, ident.read_recording(args.validate, **columns)
        else:
            if not 0 <= args.holdout < 0.9:
                raise ValueError(f"--holdout {args.holdout} must be in 0..0.9")
            fit_part = rec.part(0.0, 1.0 - args.holdout)
            check = rec.part(1.0 - args.holdout, 1.0) if args.holdout else rec
        trim = None
        if args.trim_n is not None or args.trim_v is not None:
            guess = ident.estimate_trim(rec)
            trim = ident.Trim(
                args.trim_n if args.trim_n is not None else guess.n_pct,
                args.trim_v if args.trim_v is not None else guess.v,
            )
        # a trim point far from the data overflows the regressors: such fits are refused
        # below (no window fits, a diverging model), not warned about on stderr
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            result = ident.identify(fit_part, order=args.order, trim=trim, window=args.window)
            result.nrmse_pct = ident.validate(result, check)
    except (ValueError, OSError, LogReadError) as exc:
        print(f"sil identify: {exc}", file=sys.stderr)
        return 2
    reasons = ident.distrust(result, [rec, check] if args.validate else [rec])
    report = {
        "file": str(args.file),
        "samples": len(rec.t),
        "sample_time_s": rec.dt,
        "validated_on": str(args.validate)
        if args.validate
        else f"last {args.holdout:.0%} of the file",
        **result.as_dict(),
        "trusted": not reasons,
        "not_trusted_because": reasons,
    }
    commissioning = None
    if args.export:
        try:
            commissioning = _commissioning(result, args.export)
        except ValueError as exc:
            print(f"sil identify: {exc}", file=sys.stderr)
            return 2
    if args.out:
        _write_out(args, rec, result, report)
    _print(report, args.json)
    if reasons and not args.force:
        nothing = "; nothing exported" if args.export else ""
        print(f"sil identify: the fit is not trusted: {'; '.join(reasons)}{nothing} "
              "(--force to export it anyway)", file=sys.stderr)  # fmt: skip
        return 1
    if reasons:
        print(f"sil identify: warning: exported a fit that is not trusted: {'; '.join(reasons)}",
              file=sys.stderr)  # fmt: skip
    if commissioning is not None:
        try:
            ident.write_json(args.export, commissioning)
        except OSError as exc:
            print(f"sil identify: --export: cannot write {args.export}: {exc}", file=sys.stderr)
            return 2
    return 0


def _commissioning(result: ident.Identification, export: Path) -> dict:
    """The commissioning file's content; ValueError (naming --export and the field) for a fit
    the ECU cannot use or a file it would refuse."""
    try:
        data = ident.ecu_commissioning(result)
    except ValueError as exc:
        raise ValueError(f"--export {export}: {exc}") from None
    refusal = ident.commissioning_refusal(data)
    if refusal is not None:
        raise ValueError(
            f"--export {export}: the ECU would refuse this commissioning file ({refusal}); "
            "nothing written"
        )
    return data


def _write_out(
    args: argparse.Namespace, rec: ident.Recording, result: ident.Identification, report: dict
) -> None:
    """identify.json and the plot of the fit in --out."""
    args.out.mkdir(parents=True, exist_ok=True)
    simulated = ident.simulate(np.asarray(result.theta), result.order, rec, result.trim)
    title = f"{args.file.name}: {args.order}-order model, NRMSE {result.nrmse_pct:.2f} %"
    _plot(args.out / "identify.png", rec, simulated, title)
    ident.write_json(args.out / "identify.json", report)


def _print(report: dict, as_json: bool) -> None:
    if as_json:
        print(strict_json.dumps(report, indent=2))
        return
    for key, value in report.items():
        print(f"{key}: {value}")
