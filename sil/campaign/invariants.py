"""Figures and invariants of one case, from its probe and the injector's log.

Invariants (thresholds in the campaign's ``[invariants]``):
- ``overspeed``: the true speed never above ``max_speed_pct``;
- ``egt``: the true EGT never above the ECU's EGT limit plus ``egt_margin_K``;
- ``surge``: the compressor's surge margin (true P3 and speed on the map's surge line) never
  under ``min_surge_margin_pct``;
- ``flameout``: no flameout while the ECU is in RUN (``check_flameout``);
- ``undershoot``: in RUN, the true speed never under the ECU's flameout threshold (idle less its
  flameout margin; ``check_undershoot``);
- ``thrust_rise``: after the largest demand step, when it is a step up, the thrust reaches 95 %
  of its change within ``max_thrust_rise_s``;
- ``pump_command``: the pump voltage the ECU commands within [0, v_max], and within
  [v_min, v_max] while it runs;
- for a start from rest (``check_start``): ``idle`` (the start reaches RUN), ``hot_start`` (the
  true EGT during the start never above the ECU's start limit plus ``egt_margin_K``),
  ``hung_start`` (no SLOW_ACCEL abort), ``abort_reason`` (a start that ends without RUN says
  why); ``cool_down`` (the true EGT under 373 K within ``max_cool_down_s`` of the fuel cut);
- per ``[[bus_fault]]`` with expectations: ``detect`` (every corrupted frame rejected by its
  receiver for "E2E", else the fault bit seen in EcuStatus within ``within_ticks`` of the
  window's start), ``fallback`` (the ECU mode reached from the window's start on) and
  ``recover`` (the detected bit clear again within ``recover_within_ticks`` of the window's end).
A fault that a corrupted frame slips through is counted as missed, never waved through.
"""

from __future__ import annotations

import math

import numpy as np

from ecu import faults as ecu_faults
from ecu import modes as ecu_modes
from ecu.limiters import OWNER_EGT, OWNER_SPEED
from plant.flags import FLAMEOUT
from sil.analysis import metrics
from sil.busfault.spec import E2E_KINDS
from sil.campaign.case import CaseRun
from sil.campaign.spec import Invariants

BIT = {name: bit for bit, name in ecu_faults.NAMES.items()}
START_FIGURES = (
    "start_time_s",
    "start_egt_peak_K",
    "start_abort",
    "unburnt_fuel_kg",
    "cool_down_s",
)


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def transient(r: CaseRun) -> dict:
    """The transient figures of sil.analysis.metrics on the plant's truth: thrust rise of the
    largest demand step, EGT overshoot (true EGT), least surge margin, flameouts and least speed in
    RUN."""
    rate = r.scenario.ecu_rate_hz
    n = len(r.probe.n_pct)
    running = r.column("mode") == ecu_modes.RUN
    flags = np.nan_to_num(r.column("flags")).astype(np.int64)
    trace = {
        "time": np.arange(n) / rate,
        "command": np.asarray(r.demand[:n], dtype=float),
        "Thrust": r.column("thrust_n"),
        "EGT": r.column("egt_k"),
        "P3": r.column("p3_pa"),
        "speed_true": np.where(running, r.column("n_pct"), np.nan),
        "Flameout": ((flags & FLAMEOUT) != 0) & running,
    }
    p = r.scenario.plant
    margin = metrics.surge_margin_at(
        p.ambient_temperature_K, p.ambient_pressure_Pa, p.flight_speed_m_s
    )
    out = metrics.transient(trace, r.params.egt_limit_k, margin)
    return {k: (math.nan if v is None else v) for k, v in out.items()}


def start(r: CaseRun) -> dict:
    """sil.analysis.metrics.start_stop of a run from rest ({} for any other run) on the plant's
    truth (the true EGT and speed), with NaN (and "" for no abort) where a figure does not apply."""
    if not r.scenario.plant.standstill:
        return {}
    trace = {
        "time": np.arange(len(r.probe.n_pct)) / r.scenario.ecu_rate_hz,
        "ActuatorMode": r.column("mode"),
        "EGT": r.column("egt_k"),
        "speed_true": r.column("n_pct"),
        "AbortReason": r.column("abort_reason"),
        "UnburntFuel": r.column("unburnt_kg"),
    }
    out = metrics.start_stop(trace)
    return {
        key: out.get(key) if out.get(key) is not None else "" if key == "start_abort" else math.nan
        for key in START_FIGURES
    }


def figures(r: CaseRun) -> dict:
    p = r.probe
    n, egt, mode = r.column("n_pct"), r.column("egt_k"), r.column("mode")
    v, words = r.column("pump_v"), r.column("fault_word")
    seen = int(np.bitwise_or.reduce(words)) if words.size else 0
    error = r.column("speed_pct") - r.column("ref_pct")  # speed minus reference model, %N
    owner = r.column("owner")
    running = mode == ecu_modes.RUN
    return {
        "ticks": p.tick,
        "wall_s": r.wall_s,
        "tracking_rms_pct": _rms(error),
        "tracking_speed_loop_rms_pct": _rms(error[owner == OWNER_SPEED]),
        "tracking_mean_pct": float(np.mean(error[np.isfinite(error)])) if error.size else math.nan,
        "max_n_pct": float(n.max()) if n.size else math.nan,
        "max_egt_K": float(egt.max()) if egt.size else math.nan,
        "max_egt_time_s": float(egt.argmax()) / r.scenario.ecu_rate_hz if egt.size else math.nan,
        "egt_limit_time_s": float(np.sum(owner == OWNER_EGT)) / r.scenario.ecu_rate_hz,
        "protection_time_s": float(np.sum(running & (owner != OWNER_SPEED)))
        / r.scenario.ecu_rate_hz,
        "pump_v_min": float(v.min()) if v.size else math.nan,
        "pump_v_max": float(v.max()) if v.size else math.nan,
        "final_mode": ecu_modes.NAMES[int(mode[-1])] if mode.size else "",
        "fault_bits": " ".join(
            ecu_faults.names(seen & ~(ecu_faults.LIMITER_ACTIVE | ecu_faults.PUMP_SATURATED))
        ),
        "stalls": sum(r.stalls.values()),
        **transient(r),
        **start(r),
    }


def _detections(r: CaseRun) -> list[dict]:
    """Per bus fault: what was injected and what the ECU made of it."""
    rate = r.scenario.ecu_rate_hz
    words, mode = r.column("fault_word"), r.column("mode")
    out = []
    for index, f in enumerate(r.scenario.bus_faults):
        start, end = f.window(rate)
        events = [e for e in r.bus_events if e["fault"] == index]
        e = f.expect
        d: dict = {"fault": index, "kind": f.kind, "start_s": start / rate, "frames": len(events)}
        if e.detect == "E2E":
            corrupted = [ev for ev in events if ev["kind"] in E2E_KINDS and "e2e" in ev]
            missed = sum(ev["e2e"] == "OK" for ev in corrupted)
            d.update(expected="E2E", caught=len(corrupted) - missed, missed=missed)
            d["detected"] = (missed == 0) if corrupted else None  # None: nothing corrupted
            d["detect_ticks"] = 0 if d["detected"] else None
        elif e.detect is not None:
            hits = np.flatnonzero(words[start:] & BIT[e.detect])
            d.update(expected=e.detect)
            d["detect_ticks"] = int(hits[0]) if hits.size else None
            d["detected"] = bool(hits.size) and bool(hits[0] <= (e.within_ticks or 0))
            if e.recover_within_ticks is not None:
                clear = np.flatnonzero((words[end:] & BIT[e.detect]) == 0)
                d["recover_ticks"] = int(clear[0]) if clear.size else None
                d["recovered"] = bool(clear.size) and bool(clear[0] <= e.recover_within_ticks)
        if e.fallback_mode is not None:
            want = ecu_modes.NAMES.index(e.fallback_mode)
            hits = np.flatnonzero(mode[start:] == want)
            d["fallback_ticks"] = int(hits[0]) if hits.size else None
            d["fallback"] = bool(hits.size)
        out.append(d)
    return out


def check(r: CaseRun, inv: Invariants) -> tuple[dict, list[dict], list[str]]:
    """(figures, bus fault detections, violations) of a case."""
    fig = figures(r)
    params = r.params
    violations = []
    if fig["ticks"] < r.ticks:
        violations.append(f"run ended early: {fig['ticks']} of {r.ticks} ticks")
    if fig["max_n_pct"] > inv.max_speed_pct:
        violations.append(f"overspeed: {fig['max_n_pct']:.2f} %N > {inv.max_speed_pct:g} %N")
    egt_cap = params.egt_limit_k + inv.egt_margin_K
    if fig["max_egt_K"] > egt_cap:
        violations.append(
            f"egt: {fig['max_egt_K']:.1f} K > {egt_cap:g} K (peak at {fig['max_egt_time_s']:.2f} s)"
        )
    if fig["min_surge_margin_pct"] < inv.min_surge_margin_pct:
        violations.append(
            f"surge: margin {fig['min_surge_margin_pct']:.2f} % < {inv.min_surge_margin_pct:g} %"
        )
    if inv.check_flameout and fig["flameouts"]:
        violations.append(f"flameout: {fig['flameouts']} while in RUN")
    threshold = params.idle_pct * (1.0 - params.flameout_margin)
    if inv.check_undershoot and fig["min_speed_pct"] < threshold:
        violations.append(f"undershoot: {fig['min_speed_pct']:.2f} %N < {threshold:g} %N in RUN")
    rise = fig["thrust_rise_s"]
    step_up = fig["step_pct"] > 0.0
    if step_up and math.isfinite(inv.max_thrust_rise_s) and not rise <= inv.max_thrust_rise_s:
        violations.append(f"thrust_rise: {rise:.2f} s > {inv.max_thrust_rise_s:g} s")
    v, mode = r.column("pump_v"), r.column("mode")
    running = mode == ecu_modes.RUN
    tol = 0.0015  # the frame's 1 mV resolution and rounding
    if (
        (v < -tol).any()
        or (v > params.v_max + tol).any()
        or (running.any() and (v[running] < params.v_min - tol).any())
    ):
        violations.append(
            f"pump_command: {fig['pump_v_min']:.3f}..{fig['pump_v_max']:.3f} V outside "
            f"[{params.v_min:g}, {params.v_max:g}] V"
        )
    if inv.check_start and r.scenario.plant.standstill:
        violations += _start_violations(fig, params.start_egt_limit_k + inv.egt_margin_K)
    if math.isfinite(inv.max_cool_down_s) and "cool_down_s" in fig:
        cool = fig["cool_down_s"]
        if not cool <= inv.max_cool_down_s:
            violations.append(f"cool_down: {cool:.1f} s > {inv.max_cool_down_s:g} s")
    detections = _detections(r)
    if inv.check_faults:
        for d in detections:
            name = f"bus_fault[{d['fault']}] {d['kind']}"
            if d.get("detected") is False:
                violations.append(f"{name}: not detected ({d['expected']}) in time")
            if d.get("fallback") is False:
                violations.append(f"{name}: fallback mode not reached")
            if d.get("recovered") is False:
                violations.append(f"{name}: did not recover in time")
    return fig, detections, violations


def _start_violations(fig: dict, hot_k: float) -> list[str]:
    out = []
    abort = fig["start_abort"]
    if math.isnan(fig["start_time_s"]):
        out.append(f"idle: the start never reached RUN ({abort or 'no abort reason'})")
    if fig["start_egt_peak_K"] > hot_k:
        out.append(f"hot_start: EGT {fig['start_egt_peak_K']:.1f} K > {hot_k:g} K in the start")
    if abort == "SLOW_ACCEL":
        out.append("hung_start: aborted SLOW_ACCEL")
    if math.isnan(fig["start_time_s"]) and not abort:
        out.append("abort_reason: the start ended without RUN and without a reason")
    return out
