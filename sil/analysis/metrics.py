"""Figures of a run, computed from its trace: tracking, EGT, limiter time, faults, estimates, the
transient figures of its largest demand step (thrust rise, EGT overshoot, surge margin,
flameouts) and, for a run from rest, the start and the stop (time to idle, EGT peak, abort reason,
fuel delivered without a flame, cool-down)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ecu import modes
from ecu import start_sequencer as seq
from ecu.limiters import OWNER_EGT, OWNER_SPEED

ESTIMATES = {
    "Ap_row2": ("Est_Ap21", "Est_Ap22"),
    "Lambda": ("Est_Lambda",),
    "Theta_row2": ("Est_Theta21", "Est_Theta22"),
    "Kx": ("Gain_Kx1", "Gain_Kx2"),
    "Kr": ("Gain_Kr",),
    "Kf": ("Gain_Kf1", "Gain_Kf2"),
}
STEP_MIN_PCT = 1.0  # a demand change at least this large is a step
SETTLED_S = 1.0  # the final thrust of a step: its mean over this long before the next change
THRUST_FRACTION = 0.95  # thrust_rise_s: from the step to this fraction of the thrust change
COOL_K = 373.0  # cool_down_s: from the fuel cut to an EGT under this (100 degC)
REST_PCT = 1.0  # a run from rest begins under this speed
SurgeMargin = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (P3 Pa, N %) -> margin


def surge_margin_at(t0_k: float, p0_pa: float, u0_m_s: float) -> SurgeMargin:
    """The surge margin of the engine's compressor map at this ambient and flight speed."""
    from plant.aerothermal import make_model  # (the maps: only when a margin is wanted)
    from plant.compressor import surge_margin
    from plant.intake import intake
    from plant.interface import Ambient

    cmap = make_model(Ambient(t0_k, p0_pa, u0_m_s)).compressor
    p2, t2 = intake(p0_pa, t0_k, u0_m_s)
    return lambda p3, n: surge_margin(cmap, p2, t2, p3, n)


def load_trace(path: Path) -> dict[str, np.ndarray]:
    """trace.csv as columns keyed by signal name (units stripped from the header)."""
    with path.open() as f:
        header = f.readline().strip().split(",")
    if not header or header == [""]:
        raise ValueError(f"{path}: empty trace")
    with warnings.catch_warnings():  # an empty file is told apart below, not warned about
        warnings.simplefilter("ignore", UserWarning)
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    names = [h.split("[", 1)[0] for h in header]
    if data.size == 0:
        data = np.zeros((0, len(names)))
    if data.shape[1] != len(names):
        raise ValueError(
            f"{path}: {data.shape[1]} columns of data under {len(names)} in the header"
        )
    return {name: data[:, i] for i, name in enumerate(names)}


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def tracking_rms_pct(trace: dict[str, np.ndarray], t0: float = 0.0, t1: float = math.inf) -> float:
    """RMS of true speed minus the reference-model output, in %N, over [t0, t1)."""
    t = trace["time"]
    window = (t >= t0) & (t < t1)
    return _rms(trace["speed_true"][window] - trace["ReferenceSpeed"][window])


def command_smoothness(trace: dict[str, np.ndarray], t0: float, t1: float) -> dict[str, float]:
    """The pump command and the gas over [t0, t1) (a constant demand): the command's standard
    deviation, peak to peak and mean change per tick (V), the frequency of its strongest swing
    (Hz), and T4's peak to peak (K, the plant's truth)."""
    t = trace["time"]
    window = (t >= t0) & (t < t1) & np.isfinite(trace["PumpVoltageTarget"])
    v = trace["PumpVoltageTarget"][window]
    peak_hz = math.nan
    if v.size > 2:
        power = np.abs(np.fft.rfft(v - v.mean())) ** 2
        hz = np.fft.rfftfreq(v.size, float(np.median(np.diff(t[window]))))
        peak_hz = float(hz[1:][np.argmax(power[1:])])
    t4 = trace["T4"][window]
    t4 = t4[np.isfinite(t4)]
    return {
        "pump_v_std": float(np.std(v)) if v.size else math.nan,
        "pump_v_p2p": float(np.ptp(v)) if v.size else math.nan,
        "pump_v_step_mean": float(np.mean(np.abs(np.diff(v)))) if v.size > 1 else math.nan,
        "pump_v_peak_hz": peak_hz,
        "t4_p2p_K": float(np.ptp(t4)) if t4.size else math.nan,
    }


def speed_loop_rms_pct(trace: dict[str, np.ndarray]) -> float:
    """Tracking RMS over the ticks where the control law owned the pump command: the tracking
    itself, without the time a protection (EGT, acceleration, overspeed, floor) held the engine
    off its reference."""
    free = trace["LoopOwner"] == OWNER_SPEED
    return _rms(trace["speed_true"][free] - trace["ReferenceSpeed"][free])


def fault_events(trace: dict[str, np.ndarray], bit_names: dict[int, str]) -> list[dict]:
    """Each fault bit's rising edges with their times."""
    words = np.nan_to_num(trace["FaultWord"]).astype(np.int64)
    events = []
    previous = np.concatenate(([0], words[:-1]))
    for bit, name in bit_names.items():
        rising = np.flatnonzero((words & bit) & ~(previous & bit))
        events += [{"time_s": float(trace["time"][i]), "fault": name} for i in rising]
    return sorted(events, key=lambda e: (e["time_s"], e["fault"]))


def final_estimates(trace: dict[str, np.ndarray]) -> dict[str, list[float] | float]:
    out: dict[str, list[float] | float] = {}
    for key, columns in ESTIMATES.items():
        values = [float(trace[c][-1]) if len(trace[c]) else math.nan for c in columns]
        out[key] = values if len(values) > 1 else values[0]
    return out


def summarize(trace: dict[str, np.ndarray], period_s: float, bit_names: dict[int, str]) -> dict:
    egt = trace["EGT"]
    owner = trace["LoopOwner"]
    return {
        "tracking_rms_pct": tracking_rms_pct(trace),
        "tracking_speed_loop_rms_pct": speed_loop_rms_pct(trace),
        "max_egt_K": float(np.nanmax(egt)) if np.isfinite(egt).any() else math.nan,
        "egt_limit_time_s": float(np.sum(owner == OWNER_EGT) * period_s),
        "faults": fault_events(trace, bit_names),
        "estimates": final_estimates(trace),
    }


def largest_step(trace: dict[str, np.ndarray]) -> tuple[int, int] | None:
    """(first tick of the largest demand step, first tick of the next change or the end)."""
    demand = np.nan_to_num(trace["command"])
    changes = np.flatnonzero(np.abs(np.diff(demand)) >= STEP_MIN_PCT) + 1
    if not len(changes):
        return None
    k = int(np.argmax(np.abs(demand[changes] - demand[changes - 1])))
    end = int(changes[k + 1]) if k + 1 < len(changes) else len(demand)
    return int(changes[k]), end


def thrust_rise_s(trace: dict[str, np.ndarray]) -> float | None:
    """Time from the largest demand step to 95 % of the thrust change it settles to (a rise or
    a fall; 14 CFR 33.73 asks 5 s from idle); None without a step or if it never gets there."""
    step = largest_step(trace)
    if step is None:
        return None
    i, end = step
    t, thrust = trace["time"], trace["Thrust"]
    settled = (t[:end] >= t[end - 1] - SETTLED_S) & (np.arange(end) >= i)
    before, after = float(thrust[i - 1]), float(np.mean(thrust[:end][settled]))
    target = before + THRUST_FRACTION * (after - before)
    reached = np.flatnonzero((thrust[i:end] - target) * np.sign(after - before) >= 0.0)
    return float(t[i + reached[0]] - t[i - 1]) if len(reached) else None


def transient(
    trace: dict[str, np.ndarray], egt_limit_k: float, surge_margin: SurgeMargin
) -> dict[str, float | int | None]:
    """Transient figures of a run: its largest demand step (signed, %N) and the thrust's rise
    (or fall) after it, the EGT's overshoot over the limit (0 when under), the least surge margin
    (%, from the true P3 and speed), the flameouts (rising edges of the plant's flag while the
    ECU is in RUN) and the least true speed after the step (the whole run without one)."""
    egt = trace["EGT"]
    ok = np.isfinite(trace["P3"]) & np.isfinite(trace["speed_true"])
    margin = surge_margin(trace["P3"][ok], trace["speed_true"][ok])
    flame = np.nan_to_num(trace["Flameout"]).astype(np.int64)
    if "ActuatorMode" in trace:  # a flame out while the ECU runs the engine (not starting it)
        flame = flame * (trace["ActuatorMode"] == modes.RUN)
    step = largest_step(trace)
    after = trace["speed_true"][step[0] if step else 0 :]
    demand = trace["command"]
    return {
        "step_pct": float(demand[step[0]] - demand[step[0] - 1]) if step else None,
        "thrust_rise_s": thrust_rise_s(trace),
        "egt_overshoot_K": max(0.0, float(np.nanmax(egt)) - egt_limit_k) if len(egt) else None,
        "min_surge_margin_pct": float(100.0 * margin.min()) if len(margin) else None,
        "flameouts": int(np.sum(np.diff(flame, prepend=0) > 0)),
        "min_speed_pct": float(np.nanmin(after)) if np.isfinite(after).any() else None,
    }


def cool_down_ticks(egt: np.ndarray, cut: int) -> float:
    """Ticks from the fuel cut (index ``cut``) until the EGT is under COOL_K for good (it dips
    as the gas cools at once and rises again as the slowing flow takes the metal's heat); NaN if
    it ends over COOL_K."""
    over = np.flatnonzero(~(egt[cut:] < COOL_K))
    if not len(over):
        return 0.0
    last = int(over[-1])
    return float(last + 1) if last + 1 < len(egt) - cut else math.nan


def start_stop(trace: dict[str, np.ndarray]) -> dict[str, float | int | str | None]:
    """The start and stop of a run from rest ({} for any other run): time from the arming to
    RUN (None if it never got there), the EGT's peak before it, the abort reason (None without
    an abort) and the time from the arming to it, relights (RUN -> ARMED), the fuel the pump
    delivered while no flame burnt, the time from the fuel cut (the first SHUTDOWN) until the
    EGT is under COOL_K for good (None without a cut, NaN if it never is), the final EGT."""
    t, mode, egt = trace["time"], trace["ActuatorMode"], trace["EGT"]
    speed = trace["speed_true"][np.isfinite(trace["speed_true"])]  # (in real time the first
    if not len(speed) or not speed[0] < REST_PCT:  # rows may come before the plant's first frame)
        return {}
    armed = np.flatnonzero(mode == modes.ARMED)
    if not len(armed):
        return {}
    i0 = int(armed[0])
    run = np.flatnonzero(mode[i0:] == modes.RUN)
    stop = np.flatnonzero(mode[i0:] == modes.SHUTDOWN)
    end = i0 + int(run[0]) if len(run) else i0 + int(stop[0]) if len(stop) else len(t)
    reason = int(np.nan_to_num(trace["AbortReason"])[-1])
    cut = i0 + int(stop[0]) if len(stop) else None
    was_run = (mode[:-1] == modes.RUN) & (mode[1:] == modes.ARMED)
    aborted = reason != 0 and not len(run) and end < len(t)
    period = float(t[1] - t[0]) if len(t) > 1 else 0.0
    unburnt = trace["UnburntFuel"]
    return {
        "start_time_s": float(t[i0 + run[0]] - t[i0]) if len(run) else None,
        "start_egt_peak_K": float(np.nanmax(egt[i0:end])) if end > i0 else None,
        "start_abort": seq.REASONS[reason] if reason else None,
        "start_abort_s": float(t[end] - t[i0]) if aborted else None,
        "relights": int(np.sum(was_run)),
        "unburnt_fuel_kg": float(np.nanmax(unburnt)) if np.isfinite(unburnt).any() else None,
        "cool_down_s": cool_down_ticks(egt, cut) * period if cut is not None else None,
        "final_egt_K": float(egt[-1]),
    }
