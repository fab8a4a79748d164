"""A run's results: summary.json (status, figures, faults, the nodes' own figures),
the plots, and what could not be written."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from ecu import faults as ecu_faults
from ecu.params import preset
from protocol.busload import bus_load_pct
from sil.analysis import metrics
from sil.record import mdf, results
from sil.record.canlog import convert
from sil.record.recorder import Recorder
from sil.run.command_node import CommandNode
from sil.run.config import (
    RunOptions,
    handshake_files,
)
from sil.run.processes import (
    node_stats,
)
from sil.run.recorder_process import RecorderProcess
from sil.run.state import RunState
from sil.scenario import Scenario

TOUCHED = "touched"  # the run flew to its end, but another sender's frames may be in its record
# fault bits listed in the summary: all but the two that only describe the present tick
REPORTED_FAULTS = {
    bit: name
    for bit, name in ecu_faults.NAMES.items()
    if not bit & (ecu_faults.LIMITER_ACTIVE | ecu_faults.PUMP_SATURATED)
}


def _isolation(state: RunState) -> dict:
    """On a bus: the run's RunId and tag, and the other runs' frames it heard and dropped."""
    if state.run_bus is None:
        return {}
    senders = {"run_senders": state.senders} if state.senders else {}
    return {"run_id": state.run_id, **senders, **state.run_bus.stats()}


def _egt_limit_k(s: Scenario) -> float:
    return preset(s.controller.preset or "default", **s.controller.params).egt_limit_k


def _transient(s: Scenario, trace: dict) -> dict:
    """metrics.transient with the ECU's EGT limit and the surge line of the scenario's engine."""
    p = s.plant
    margin = metrics.surge_margin_at(
        p.ambient_temperature_K, p.ambient_pressure_Pa, p.flight_speed_m_s
    )
    return metrics.transient(trace, _egt_limit_k(s), margin)


def finish(
    opts: RunOptions,
    s: Scenario,
    seed: int,
    recorder: Recorder | RecorderProcess,
    command: CommandNode,
    state: RunState,
    wall: float,
) -> dict:
    totals = recorder.totals()
    sim_time = totals["tick"] / s.ecu_rate_hz
    period = 1.0 / s.ecu_rate_hz
    trace = None
    try:
        trace = metrics.load_trace(opts.out_dir / "trace.csv")
    except (OSError, ValueError) as exc:  # a recorder that died mid-run: the rest is reported
        state.status = "aborted"
        state.abort_reason = state.abort_reason or f"trace.csv cannot be read: {exc}"
    summary = {
        "status": state.status,
        "abort_reason": state.abort_reason,
        "scenario": s.name,
        "mode": opts.mode,
        "bus": state.bus,
        **_isolation(state),
        **({"inproc_loop": state.loop} if state.loop else {}),
        **({"ecu_bus": state.ecu_bus} if state.ecu_bus else {}),
        "seed": seed,
        "run": {k: v for k, v in state.record.items() if k != "format"},
        **({"warnings": state.warnings} if state.warnings else {}),
        "sim_time_s": sim_time,
        "wall_time_s": wall,
        "realtime_factor": sim_time / wall if wall > 0 else math.nan,
        # on a bus: what of wall_time_s went to starting the node processes (before tick 0)
        **({"startup_s": state.nodes_up - state.started} if state.nodes_up else {}),
        "frames": totals["frames"],
        "bus_load_pct": bus_load_pct(totals["bits"], sim_time),
        "missed_ticks": totals["missed_ticks"],
        **(metrics.summarize(trace, period, REPORTED_FAULTS) if trace is not None else {}),
        **(_transient(s, trace) if trace is not None and len(trace["time"]) > 1 else {}),
        **(metrics.start_stop(trace) if trace is not None else {}),
        "faults_injected": [{"time_s": i["tick"] / s.ecu_rate_hz, **i} for i in command.injected],
        "bus_faults_injected": state.bus_fault_events,
        **({"bridge_errors": state.bridge_errors} if state.bridge_errors else {}),
        "e2e": {m: c for m, c in totals["e2e"].items() if set(c) - {"OK"}},
        **({"nodes": nodes} if (nodes := node_stats(opts.out_dir)) else {}),
        # the image's own figures (--ecu-impl pil), taken out of the ECU node's
        **({"pil": pil} if (pil := nodes.get("ecu", {}).pop("pil", None)) else {}),
        "unknown_ids": {f"0x{k:X}": v for k, v in totals["unknown_ids"].items()},
        "wrong_length": {f"0x{k:X}": v for k, v in totals["wrong_length"].items()},
    }
    if state.status == "completed" and totals["tick"] < len(command.commands):
        summary["status"] = "aborted"
        summary["abort_reason"] = summary["abort_reason"] or (
            f"the run ended early: the ECU answered {totals['tick']} of "
            f"{len(command.commands)} ticks"
        )
    if state.ended_early is not None:
        summary["ended_early"] = _ended_early(state.ended_early, summary)
    if state.turn_watch is not None and state.turn_watch.looked:
        summary["slow_turns"] = state.turn_watch.looked
    _other_senders(summary)
    for name in ("ecu", "plant"):
        log = opts.out_dir / f"{name}.log"
        if log.exists():
            summary[f"{name}_log"] = log.name
    tick0 = state.started_wall + (state.nodes_up - state.started if state.nodes_up else 0.0)
    summary[mdf.TICK0_FIELD] = mdf.format_start(round(tick0 * 1e6))  # (every log's start)
    for fmt in opts.log_formats:
        try:
            convert(opts.out_dir / "can.log", fmt, start_s=tick0)
        except results.WriteError as exc:
            state.write_errors.append(str(exc))
    if opts.plots and trace is not None:
        summary["plots"] = _plots(opts, s, trace, state)
    _write_summary(opts.out_dir, summary, state)
    for path in handshake_files(opts.out_dir):
        path.unlink(missing_ok=True)
    return results.status_first(summary)


def _ended_early(ended: dict, summary: dict) -> dict:
    """Which node ended the run early, when and why, with what its own figures say of its pace
    in real time (the periods it overran, its worst lateness), also in the abort reason."""
    node = summary.get("nodes", {}).get(ended["node"], {})
    if not node.get("overruns"):
        return ended
    late = node.get("jitter_ms", {}).get("max", 0.0)
    pace = (
        f"its process overran {node['overruns']} of {node['periods']} periods, "
        f"{late:.0f} ms late at worst"
    )
    summary["abort_reason"] += f"; {pace}"
    return {**ended, "overruns": node["overruns"], "worst_lateness_ms": late}


def _other_senders(summary: dict) -> None:
    """Another sender's frames on the run's bus (heard by the recorder or a node). Where the
    run's senders were named before tick 0 (``run_senders``), every frame of another sender was
    dropped by who sent it, and the record is the run's alone: an undisturbed run warns of them,
    a disturbed one (aborted, or with missed ticks) is aborted saying so first. Where frames
    carry no sender, the run cannot tell that its record holds none of them: it is ``touched``,
    saying so first, with the first frame dropped."""
    counts = [summary.get("other_sender_frames", 0)]
    ids = set(summary.get("other_sender_ids", {}))
    firsts = [f"run: {summary['other_sender_first'][0]}"] if "other_sender_first" in summary else []
    for name, node in summary.get("nodes", {}).items():
        counts.append(node.get("other_sender_frames", 0))
        ids |= set(node.get("other_sender_ids", {}))
        if "other_sender_first" in node:
            firsts.append(f"{name}: {node['other_sender_first'][0]}")
    frames = max(counts)
    if not frames:
        return
    listed = sorted(ids, key=lambda i: int(i, 16))
    shown = ", ".join(listed[:6]) + (", ..." if len(listed) > 6 else "")
    first = f"; first dropped by {firsts[0]}" if firsts else ""
    said = (
        f"foreign frames on the bus: {frames:,} from another sender (IDs {shown}{first}) — "
        "the run's bus is shared"
    )
    if summary["status"] != "completed" or summary["missed_ticks"]:
        why = summary["abort_reason"] or f"{summary['missed_ticks']} missed ticks"
        summary["status"] = "aborted"
        summary["abort_reason"] = f"{said} ({why})"
    elif "run_senders" not in summary:
        summary["status"] = TOUCHED
        summary["abort_reason"] = (
            f"{said}; its frames name no sender, so the run's record may hold some of them"
        )
    else:
        warning = f"{said}; they were left out of the run (not one of the run's senders)"
        summary.setdefault("warnings", []).append(warning)
        print(f"sil run: warning: {warning}", file=sys.stderr)


def _plots(opts: RunOptions, s: Scenario, trace: dict, state: RunState) -> list[str]:
    """Write the run's plots; the names written (a plot that cannot be written is noted in
    ``state.write_errors``, and the rest are not tried)."""
    from sil.analysis import plots  # matplotlib: only when plotting (campaign runs do not)

    title = f"{s.name} ({s.controller.kind}, {s.plant.model} plant)"
    limit = _egt_limit_k(s)
    try:
        return [
            p.name for p in plots.plot_run(trace, opts.out_dir, title, s.controller.kind, limit)
        ]
    except results.WriteError as exc:
        state.write_errors.append(str(exc))
        return [name for name in results.PLOTS if (opts.out_dir / name).is_file()]


def _write_summary(out_dir: Path, summary: dict, state: RunState) -> None:
    """The final summary; a run whose results could not all be written is aborted, naming the
    first file, and lists what it kept. If even the summary cannot be written, a compact one
    goes over the ``running`` one in its space; the returned summary says why either way."""
    if state.write_errors:
        _not_all_written(out_dir, summary, state)
    try:
        results.write_summary(out_dir, summary)
        return
    except results.WriteError as exc:
        state.write_errors.append(str(exc))
    _not_all_written(out_dir, summary, state)
    keys = ("status", "abort_reason", "scenario", "write_errors", "kept")
    try:  # the least that says what happened, in the room the running summary had
        results.write_summary_in_place(out_dir, {k: summary[k] for k in keys})
    except results.WriteError:
        summary["kept"] = [name for name in summary["kept"] if name != results.SUMMARY]


def _not_all_written(out_dir: Path, summary: dict, state: RunState) -> None:
    summary["status"] = "aborted"
    summary["abort_reason"] = summary["abort_reason"] or state.write_errors[0]
    summary["write_errors"] = list(state.write_errors)
    summary["kept"] = sorted({*results.kept(out_dir), results.SUMMARY})
