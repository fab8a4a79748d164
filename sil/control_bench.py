"""`sil bench control`: how smooth the pump command is at constant demand, and what it costs in
tracking, for the MRAC, the document's PID and the tuned PI, on the aero-thermal plant.

The figures are those of the window 3-9.5 s of the 70-100 %N staircase (a constant 90 %N demand):
the pump command's standard deviation, peak to peak and mean change per tick, and the gas
temperature T4's peak to peak (the plant's truth); with each run's tracking RMS (speed minus the
reference model; also over the ticks the control law owned the fuel). The MRAC also flies:

- without sensor noise (speed and EGT): what is left is the MRAC's own limit cycle;
- with a gentler reference model and the speed-rate filter (ecu.rate_filter), the trade between
  smoothness and tracking (quick: two of the points).

And the plant's shaft rate per pump volt at 1, 8 and 50 rad/s (linearised at 90 %N) against the
commissioned fast model's (eq. 3.24), which explains the limit cycle (docs/ecu.md).

Targets (the MRAC, the document's scenario): pump command std <= 0.05 V and T4 peak to peak <=
25 K at constant demand, with the staircase's tracking RMS <= 0.20 %N."""

from __future__ import annotations

import tempfile
import tomllib
from pathlib import Path

import numpy as np

from ecu.params import AP_ROW2_EQ_3_23, EcuParams
from plant.aerothermal import make_model
from plant.linearise import speed_rate_per_volt, steady_at_speed
from sil import metrics
from sil.bench import completed_run
from sil.campaign.tomlw import dumps
from sil.scenario import load

WINDOW_S = (3.0, 9.5)
RUNS = {"mrac": "thesis-5.4-staircase", "pid": "thesis-6.2-staircase-pid", "pi": "staircase-pi"}
# (reference natural frequency rad/s, damping, rate filter bandwidth rad/s or 0 for off)
TRADE = ((5.0, 1.0, 8.0), (3.0, 0.85, 8.0), (3.0, 0.7, 6.0), (2.5, 0.7, 6.0))
QUICK_TRADE = TRADE[1:3]
OMEGAS = (1.0, 8.0, 50.0)

TARGET_TEXT = {
    "mrac_std": "MRAC at constant demand: pump command std <= 0.05 V",
    "mrac_t4": "MRAC at constant demand: T4 peak to peak <= 25 K",
    "mrac_rms": "MRAC on the staircase: tracking RMS <= 0.20 %N",
}


def _variant(name: str, folder: Path, plant: dict, params: dict) -> Path:
    """A copy of the shipped scenario with plant fields and ECU parameters changed."""
    data = tomllib.loads(load(name).path.read_text())
    data["plant"].update(plant)
    data["controller"].setdefault("params", {}).update(params)
    path = folder / f"{name}-{len(list(folder.glob('*.toml')))}.toml"
    path.write_text(dumps(data))
    return path


def _fly(path: Path, out: Path) -> dict:
    """One in-process run with the C ECU: its window figures and tracking."""
    summary = completed_run(path, out, "--mode", "inproc", "--ecu-impl", "c")
    trace = metrics.load_trace(out / "trace.csv")
    return {
        **metrics.command_smoothness(trace, *WINDOW_S),
        "tracking_rms_pct": summary["tracking_rms_pct"],
        "tracking_speed_loop_rms_pct": summary["tracking_speed_loop_rms_pct"],
    }


def _reference(wn: float, zeta: float, rf_bw: float) -> dict:
    """ECU parameters for a reference model (and the rate filter), with the ideal gains of the
    commissioned fast model as the MRAC's start (eq. 5.15: K_x = (A_m - A_p) / Lambda)."""
    lam = EcuParams().init_lambda
    a21, a22 = AP_ROW2_EQ_3_23
    params = {
        "ref_wn": wn,
        "ref_zeta": zeta,
        "init_kx": [(-wn * wn - a21) / lam, (-2.0 * zeta * wn - a22) / lam],
        "init_kr": wn * wn / lam,
    }
    if rf_bw:
        params.update(rate_filter_on=1, rate_filter_bw=rf_bw)
    return params


def _plant_rate() -> dict:
    """The shaft's rate per pump volt, linearised at 90 %N, against the fast model's."""
    model = make_model()
    steady, g_fuel = steady_at_speed(model, 90.0)
    plant = speed_rate_per_volt(model, steady, g_fuel, np.array(OMEGAS))
    lam = EcuParams().init_lambda
    a21, a22 = AP_ROW2_EQ_3_23
    out = {}
    for w, got in zip(OMEGAS, plant, strict=True):
        s = 1j * w
        out[f"plant_rate_per_v_{w:g}_rad_s"] = round(float(got), 3)
        out[f"fast_model_rate_per_v_{w:g}_rad_s"] = round(abs(s * lam / (s * s - a22 * s - a21)), 3)
    return out


def run(quick: bool = False) -> dict:
    figures: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for key, name in RUNS.items():
            for field, value in _fly(load(name).path, folder / key).items():
                figures[f"{key}_{field}"] = round(value, 4)
        quiet = _variant(RUNS["mrac"], folder, {"speed_noise_rpm": 0.0, "egt_noise_K": 0.0}, {})
        for field, value in _fly(quiet, folder / "quiet").items():
            figures[f"mrac_noise_free_{field}"] = round(value, 4)
        for wn, zeta, rf_bw in QUICK_TRADE if quick else TRADE:
            tag = f"mrac_wn{wn:g}_z{zeta:g}_rf{rf_bw:g}"
            path = _variant(RUNS["mrac"], folder, {}, _reference(wn, zeta, rf_bw))
            got = _fly(path, folder / tag)
            for field in ("pump_v_std", "t4_p2p_K", "tracking_rms_pct"):
                figures[f"{tag}_{field}"] = round(got[field], 4)
    figures.update(_plant_rate())
    figures["targets_met"] = {
        "mrac_std": figures["mrac_pump_v_std"] <= 0.05,
        "mrac_t4": figures["mrac_t4_p2p_K"] <= 25.0,
        "mrac_rms": figures["mrac_tracking_rms_pct"] <= 0.20,
    }
    return figures
