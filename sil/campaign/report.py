"""The campaign report: ``report.md`` with PNG plots, from ``results.csv``.

- tracking RMS per controller across the engine variation (percentiles, the nominal engine's,
  and the targets: MRAC 95th percentile within 2x its nominal, MRAC median below the PID's);
- per bus fault class: detection rate, time to detect, fallback and recovery;
- for starts from rest: how many reached idle, the start times (median, p95, max), the EGT's
  peak in the start, the aborts by reason, the fuel delivered without a flame, the cool-down;
- invariant violations and failures, each with the ``sil run`` line that reproduces the run.
"""

from __future__ import annotations

import csv
import json
import math
import shlex
from collections import defaultdict
from pathlib import Path

import numpy as np

CONTROLLER = "controller.kind"
HELD_S = 5.0  # a protection owning the fuel this long in a run holds the engine off its demand
# (each step's brush with the acceleration line or a rate loop lasts tenths of a second)


def load(path: Path) -> list[dict]:
    """The table's rows in run order, the last one of each run (a resumed campaign appends)."""
    with path.open(newline="") as f:
        last = {r["run_id"]: r for r in csv.DictReader(f)}
    return [last[k] for k in sorted(last)]


def _float(v: str) -> float:
    try:
        return float(v)
    except ValueError:
        return math.nan


def repro(out: Path, row: dict) -> str:
    """The command line that reruns a case with full recording (can.log, trace, plots)."""
    run_id = row["run_id"]
    scenario = out / "scenarios" / f"{run_id}.toml"
    argv = ["sil", "run", str(scenario), "--mode", "inproc", "--out", str(out / "repro" / run_id)]
    if row.get("ecu_impl", "python") != "python":
        argv += ["--ecu-impl", row["ecu_impl"]]
    return shlex.join(argv)


def _pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if x.size else math.nan


def tracking(rows: list[dict]) -> dict[str, dict]:
    """Per controller: tracking RMS percentiles over the varied engines, and the nominal's."""
    out: dict[str, dict] = {}
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        if r["status"] == "completed":
            groups[r.get(CONTROLLER) or "base"].append(r)
    for name, rs in sorted(groups.items()):
        engines = [r for r in rs if r["sample"] != "-1"]
        varied = np.array([_float(r["tracking_rms_pct"]) for r in engines])
        # engines a protection held off the demand: it owned the fuel for HELD_S or more
        limited = np.array(
            [_float(r.get("protection_time_s", "")) >= HELD_S for r in engines], dtype=bool
        )
        free = varied[~limited & np.isfinite(varied)]
        limited &= np.isfinite(varied)
        varied = varied[np.isfinite(varied)]
        nominal = [_float(r["tracking_rms_pct"]) for r in rs if r["sample"] == "-1"]
        # time on limiters: a protection, not the speed loop, owned the fuel
        held_s = np.array([_float(r.get("protection_time_s", "")) for r in engines])
        held_s = held_s[np.isfinite(held_s)]
        nominal_held_s = [_float(r.get("protection_time_s", "")) for r in rs if r["sample"] == "-1"]
        offset = np.array([abs(_float(r.get("tracking_mean_pct", ""))) for r in rs])
        out[name] = {
            "runs": int(varied.size),
            "nominal": nominal[0] if nominal else math.nan,
            **{f"p{q}": _pct(varied, q) for q in (5, 50, 95)},
            "max": float(varied.max()) if varied.size else math.nan,
            "limited": int(limited.sum()),
            "p95_free": _pct(free, 95),
            "offset": float(np.nanmedian(offset)) if np.isfinite(offset).any() else math.nan,
            "limiter_s_nominal": nominal_held_s[0] if nominal_held_s else math.nan,
            "limiter_s_p50": _pct(held_s, 50),
            "limiter_s_mean": float(held_s.mean()) if held_s.size else math.nan,
            "values": varied,
        }
    return out


def detection(rows: list[dict]) -> dict[str, dict]:
    """Per bus fault class (kind and expectation): runs, detection, fallback, recovery."""
    classes: dict[str, dict] = {}
    for r in rows:
        if r["status"] != "completed" or not r["detections"]:
            continue
        for d in json.loads(r["detections"]):
            key = f"{r.get('variant') or d['kind']} ({d['kind']}"
            key += f", {d['expected']})" if "expected" in d else ")"
            c = classes.setdefault(
                key, {"runs": 0, "detected": 0, "judged": 0, "ticks": [], "fallback": [],
                      "recovered": [], "caught": 0, "missed": 0}
            )  # fmt: skip
            c["runs"] += 1
            if d.get("detected") is not None:
                c["judged"] += 1
                c["detected"] += bool(d["detected"])
            if d.get("detect_ticks") is not None:
                c["ticks"].append(d["detect_ticks"])
            c["caught"] += d.get("caught", 0)
            c["missed"] += d.get("missed", 0)
            if "fallback" in d:
                c["fallback"].append(bool(d["fallback"]))
            if "recovered" in d:
                c["recovered"].append(bool(d["recovered"]))
    return classes


TRANSIENT_STEP_PCT = 20.0  # a largest demand step at least this large makes a run a transient


def transients(rows: list[dict]) -> list[dict]:
    """Per controller and variant, over the runs whose largest demand step is a transient: the
    thrust rise (nominal engine, median, p95, max), the worst EGT overshoot, the least surge
    margin, the runs with a flameout and the least speed."""
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in rows:
        if r["status"] == "completed" and abs(_float(r.get("step_pct", ""))) >= TRANSIENT_STEP_PCT:
            groups[(r.get(CONTROLLER) or "base", r.get("variant") or "-")].append(r)
    out = []
    for (name, variant), rs in sorted(groups.items()):

        def col(key: str, rs: list[dict] = rs) -> np.ndarray:
            return np.array([_float(r[key]) for r in rs])

        rise = col("thrust_rise_s")
        nominal = [_float(r["thrust_rise_s"]) for r in rs if r["sample"] == "-1"]
        out.append({
            "controller": name,
            "variant": variant,
            "step_pct": float(np.median(col("step_pct"))),
            "runs": len(rs),
            "rise_nominal": nominal[0] if nominal else math.nan,
            "rise_p50": float(np.nanmedian(rise)) if np.isfinite(rise).any() else math.nan,
            "rise_p95": _pct(rise[np.isfinite(rise)], 95),
            "rise_max": float(np.max(np.where(np.isfinite(rise), rise, np.inf))),
            "egt_overshoot_max": float(np.nanmax(col("egt_overshoot_K"))),
            "surge_margin_min": float(np.nanmin(col("min_surge_margin_pct"))),
            "flameout_runs": int(np.sum(col("flameouts") > 0)),
            "speed_min": float(np.nanmin(col("min_speed_pct"))),
        })  # fmt: skip
    return out


def _plots(rows: list[dict], track: dict, classes: dict, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    if any(t["runs"] for t in track.values()):
        fig, ax = plt.subplots(figsize=(8, 4.5))
        hi = max(float(t["values"].max()) for t in track.values() if t["runs"])
        bins = np.linspace(0.0, hi * 1.02, 50)
        for name, t in track.items():
            if t["runs"]:
                ax.hist(t["values"], bins=bins, alpha=0.55, label=f"{name} ({t['runs']} engines)")
                if math.isfinite(t["nominal"]):
                    ax.axvline(t["nominal"], ls="--", lw=1, color=ax.patches[-1].get_facecolor())
        ax.set_xlabel("tracking RMS against the reference model [%N]")
        ax.set_ylabel("runs")
        ax.set_title("Tracking error across engine variation (dashed: nominal engine)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(out / "tracking_rms.png", dpi=110)
        plt.close(fig)
        names.append("tracking_rms.png")
    ticks = {k: c["ticks"] for k, c in classes.items() if c["ticks"]}
    if ticks:
        fig, ax = plt.subplots(figsize=(8, 0.6 + 0.5 * len(ticks)))
        ax.boxplot(list(ticks.values()), orientation="horizontal", tick_labels=list(ticks))
        ax.set_xlabel("time to detect [ECU periods from the fault's start]")
        ax.set_title("Time to detect per bus fault class")
        fig.tight_layout()
        fig.savefig(out / "time_to_detect.png", dpi=110)
        plt.close(fig)
        names.append("time_to_detect.png")
    return names


def starts(rows: list[dict]) -> dict | None:
    """Over the runs that started from rest: runs, how many reached RUN, the start times and
    EGT peaks (median, p95, max), the aborts by reason, the unburnt fuel's max and the cool-down
    times (median, max); None without such runs."""
    rs = [r for r in rows if r["status"] == "completed" and r.get("start_egt_peak_K", "") != ""]
    if not rs:
        return None

    def col(key: str) -> np.ndarray:
        return np.array([_float(r[key]) for r in rs])

    t, egt, cool = col("start_time_s"), col("start_egt_peak_K"), col("cool_down_s")
    reached = t[np.isfinite(t)]
    aborts: dict[str, int] = defaultdict(int)
    for r in rs:
        if r["start_abort"]:
            aborts[r["start_abort"]] += 1
    nominal = [_float(r["start_time_s"]) for r in rs if r["sample"] == "-1"]
    return {
        "runs": len(rs),
        "reached": int(reached.size),
        "time_nominal": nominal[0] if nominal else math.nan,
        "time": (_median(reached), _pct(reached, 95), _max(reached)),
        "egt": (_median(egt), _pct(egt[np.isfinite(egt)], 95), _max(egt)),
        "aborts": dict(sorted(aborts.items())),
        "unburnt_max_g": 1000.0 * _max(col("unburnt_fuel_kg")),
        "cool": (_median(cool), _max(cool)),
        "cooled": int(np.sum(np.isfinite(cool))),
    }


def _median(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else math.nan


def _max(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(x.max()) if x.size else math.nan


def _fmt(x: float, spec: str = ".3f") -> str:
    return format(x, spec) if math.isfinite(x) else "-"


def write(out: Path, title: str, speed: dict | None = None) -> Path:
    """report.md (and plots) in ``out`` from ``out/results.csv``; ``speed``: runs/min etc."""
    rows = load(out / "results.csv")
    track, classes = tracking(rows), detection(rows)
    plots = _plots(rows, track, classes, out)
    done = [r for r in rows if r["status"] == "completed"]
    failed = [r for r in rows if r["status"] == "failed"]
    violating = [r for r in done if r["n_violations"] not in ("", "0")]
    walls = np.array([_float(r["wall_s"]) for r in done])
    lines = [f"# Campaign {title}", ""]
    lines.append(f"- runs: {len(rows)} ({len(done)} completed, {len(failed)} failed), "
                 f"{len(violating)} with invariant violations")  # fmt: skip
    if walls.size:
        lines.append(
            f"- wall time per run: median {np.median(walls):.2f} s, max {walls.max():.2f} s"
        )
    for key, value in (speed or {}).items():
        lines.append(f"- {key}: {value}")
    lines.append("")
    steps = transients(rows)
    if any(t["runs"] for t in track.values()):
        lines += ["## Tracking RMS across engine variation [%N]", "",
                  "| controller | engines | nominal | p5 | median | p95 | max | p95 / nominal "
                  "| median of mean error | time on limiters [s] nominal / median / mean |",
                  "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for name, t in track.items():
            ratio = t["p95"] / t["nominal"] if t["nominal"] else math.nan
            lines.append(
                f"| {name} | {t['runs']} | {_fmt(t['nominal'])} | {_fmt(t['p5'])} | "
                f"{_fmt(t['p50'])} | {_fmt(t['p95'])} | {_fmt(t['max'])} | {_fmt(ratio, '.2f')} "
                f"| {_fmt(t['offset'])} | {_fmt(t['limiter_s_nominal'], '.1f')} / "
                f"{_fmt(t['limiter_s_p50'], '.1f')} / {_fmt(t['limiter_s_mean'], '.1f')} |"
            )
        lines.append("")
        if not steps:  # the staircase's targets: of no meaning across idle-to-maximum steps
            lines += _targets(track)
        lines += ["", "![tracking](tracking_rms.png)", ""]
    if steps:
        lines += ["## Transients", "",
                  "| controller | variant | step [%N] | runs | thrust rise [s] nominal / median / "
                  "p95 / max | EGT overshoot max [K] | surge margin min [%] | runs with a "
                  "flameout | least speed [%N] |",
                  "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for s in steps:
            rise = " / ".join(
                _fmt(s[k], ".2f") for k in ("rise_nominal", "rise_p50", "rise_p95", "rise_max")
            )
            lines.append(
                f"| {s['controller']} | {s['variant']} | {s['step_pct']:+.0f} | {s['runs']} | "
                f"{rise} | {_fmt(s['egt_overshoot_max'], '.1f')} | "
                f"{_fmt(s['surge_margin_min'], '.1f')} | {s['flameout_runs']} | "
                f"{_fmt(s['speed_min'], '.1f')} |"
            )
        lines += ["", "Thrust rise: from the step to 95 % of the thrust change (a fall after a "
                  "step down); EGT overshoot over the ECU's limit, true EGT.", ""]  # fmt: skip
    start = starts(rows)
    if start is not None:
        s = start
        lines += ["## Starts", "",
                  f"- reached idle (RUN): {s['reached']} of {s['runs']}",
                  "- start time, arming to RUN [s]: nominal "
                  f"{_fmt(s['time_nominal'], '.2f')}, median {_fmt(s['time'][0], '.2f')}, "
                  f"p95 {_fmt(s['time'][1], '.2f')}, max {_fmt(s['time'][2], '.2f')}",
                  f"- EGT peak in the start [K]: median {_fmt(s['egt'][0], '.0f')}, p95 "
                  f"{_fmt(s['egt'][1], '.0f')}, max {_fmt(s['egt'][2], '.0f')}",
                  "- aborts: " + (", ".join(f"{k} {n}" for k, n in s["aborts"].items())
                                  or "none"),
                  f"- fuel delivered without a flame, max: {_fmt(s['unburnt_max_g'], '.2f')} g",
                  f"- cool-down, fuel cut to EGT under 373 K [s]: median "
                  f"{_fmt(s['cool'][0], '.1f')}, max {_fmt(s['cool'][1], '.1f')} "
                  f"({s['cooled']} of {s['runs']} runs)", ""]  # fmt: skip
    if classes:
        lines += [
            "## Bus faults",
            "",
            "| class | runs | detected | E2E caught / missed | time to detect [ticks] "
            "median / max | fallback reached | recovered |",
            "|---|---|---|---|---|---|---|",
        ]
        for key, c in classes.items():
            rate = (
                f"{c['detected']}/{c['judged']} ({100 * c['detected'] / c['judged']:.0f} %)"
                if c["judged"]
                else "-"
            )
            t = np.array(c["ticks"])
            tt = f"{np.median(t):g} / {t.max():g}" if t.size else "-"
            fb = f"{sum(c['fallback'])}/{len(c['fallback'])}" if c["fallback"] else "-"
            rc = f"{sum(c['recovered'])}/{len(c['recovered'])}" if c["recovered"] else "-"
            e2e = f"{c['caught']} / {c['missed']}" if c["caught"] or c["missed"] else "-"
            lines.append(f"| {key} | {c['runs']} | {rate} | {e2e} | {tt} | {fb} | {rc} |")
        lines.append("")
        if "time_to_detect.png" in plots:
            lines += ["![time to detect](time_to_detect.png)", ""]
    lines += ["## Invariant violations", ""]
    if not violating:
        lines += ["None.", ""]
    else:
        kinds: dict[str, int] = defaultdict(int)
        for r in violating:
            for v in r["violations"].split("; "):
                kinds[f"{v.split(':')[0]} ({r.get(CONTROLLER) or 'base'})"] += 1
        lines += ["By kind: " + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items())), ""]
    for r in violating:
        lines += [f"- run {r['run_id']}: {r['violations']}", f"  `{repro(out, r)}`"]
    if failed:
        lines += ["", "## Failed runs", ""]
        for r in failed:
            lines += [f"- run {r['run_id']}: {r['error']}", f"  `{repro(out, r)}`"]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _targets(track: dict) -> list[str]:
    """The issue's two targets, said plainly whichever way they come out."""
    mrac = track.get("mrac")
    if mrac is None or not mrac["runs"]:
        return []
    out = []
    ratio = mrac["p95"] / mrac["nominal"] if mrac["nominal"] else math.nan
    ok = ratio <= 2.0
    out.append(f"- MRAC 95th percentile {_fmt(mrac['p95'])} %N is {_fmt(ratio, '.2f')}x the "
               f"nominal engine's {_fmt(mrac['nominal'])} %N: target (within 2x) "
               f"{'met' if ok else 'NOT met'}.")  # fmt: skip
    if mrac["limited"]:
        n, held = mrac["runs"], mrac["limited"]
        free = mrac["p95_free"] / mrac["nominal"] if mrac["nominal"] else math.nan
        out.append(
            f"  On {held} of the {n} engines a protection (EGT, acceleration, topping, floor)"
            f" owned the fuel for {HELD_S:g} s or more, holding the engine off the demand (the"
            " protection, not the tracking, sets their error);"
            f" over the other {n - held} the 95th percentile is {_fmt(mrac['p95_free'])} %N,"
            f" {_fmt(free, '.2f')}x the nominal's."
        )
    for kind, name in (("pid", "PID"), ("pi", "scheduled PI")):
        base = track.get(kind)
        if base is not None and base["runs"]:
            better = mrac["p50"] < base["p50"]
            out.append(f"- MRAC median {_fmt(mrac['p50'])} %N against {name} median "
                       f"{_fmt(base['p50'])} %N: target (MRAC better) "
                       f"{'met' if better else 'NOT met'}.")  # fmt: skip
    return out
