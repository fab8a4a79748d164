"""Figures of a run, computed from its trace: tracking, EGT, limiter time, faults, estimates."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

ESTIMATES = {
    "Ap_row2": ("Est_Ap21", "Est_Ap22"),
    "Lambda": ("Est_Lambda",),
    "Theta_row2": ("Est_Theta21", "Est_Theta22"),
    "Kx": ("Gain_Kx1", "Gain_Kx2"),
    "Kr": ("Gain_Kr",),
    "Kf": ("Gain_Kf1", "Gain_Kf2"),
}
LOOP_OWNER_EGT = 1


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
        "max_egt_K": float(np.nanmax(egt)) if np.isfinite(egt).any() else math.nan,
        "egt_limit_time_s": float(np.sum(owner == LOOP_OWNER_EGT) * period_s),
        "faults": fault_events(trace, bit_names),
        "estimates": final_estimates(trace),
    }
