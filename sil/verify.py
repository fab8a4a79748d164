"""Verification of the ECU firmware against the source document, in one process (no bus).

The plant is the eq. 3.24 fast engine model (plant.fast_model.FastEngine, RK4), the ECU runs at
100 Hz and sees what a microcontroller sees: speed in whole rpm, and answers with the pump
voltage in mV. Three runs per scenario:

- ``fixed``: the integer firmware (ecu.firmware.Ecu), rate derived from speed by the ECU;
- ``float``: its float64 twin (ecu.reference.loop.FloatLoop) on the same quantised speed;
- ``float_true_rate``: the twin handed the plant's true speed and rate, as the document's
  simulation was; the difference to ``float`` is the effect of the ECU's rate filter.

Scenarios: sec. 4.2 (estimator alone, open-loop square wave of +-1 V at 0.05 Hz) and sec. 5.2
(indirect MRAC, square-wave speed command of +-1 %N at 0.05 Hz), each with the document's gains
and initial values (presets ``sec4_2_estimator`` and ``sec5_2_mrac_fast``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ecu.firmware import Ecu, EcuInputs
from ecu.modes import RUN
from ecu.params import EcuParams, preset
from ecu.reference.loop import FloatLoop
from plant.fast_model import THETA_EQ_3_23, FastEngine

Q24 = float(1 << 24)
RPM_PER_PCT = 1125.0

# published values (eq. 3.23 plant; sec. 4.2 and 5.2 results; eq. 5.9 ideal gains)
PUBLISHED = {
    "ap_row2": (THETA_EQ_3_23[0], THETA_EQ_3_23[1]),
    "lambda": THETA_EQ_3_23[2],
    "kx_ideal": (-4.809, -1.589),
    "kr_ideal_abs": 5.185,
}
ESTIMATES = ("ap21", "ap22", "lam", "th1", "th2", "kx1", "kx2", "kr", "kf1", "kf2")
SCENARIOS = {"sec4_2": "sec4_2_estimator", "sec5_2": "sec5_2_mrac_fast"}
TRACKING_WINDOW_S = 100.0  # tracking RMS over the last 100 s
TRACKING_TOL_PCT = 0.1


@dataclass
class RunResult:
    """Time histories (speed, reference-model speed, pump voltage) and the final estimates."""

    t: np.ndarray
    n_pct: np.ndarray
    nref_pct: np.ndarray
    v: np.ndarray
    estimates: dict[str, float]


def square(t: float) -> int:
    """Square wave of unit amplitude at 0.05 Hz, +1 for the first half period."""
    return 1 if (t % 20.0) < 10.0 else -1


def scenario_params(name: str, **overrides: object) -> EcuParams:
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose from {sorted(SCENARIOS)}")
    return preset(SCENARIOS[name], **overrides)


def run_fixed(p: EcuParams, seconds: float) -> RunResult:
    """The integer firmware against the eq. 3.24 plant."""
    ecu = Ecu(p)
    plant = FastEngine()
    i = EcuInputs()
    i.egt_dk = 10480  # our plant at trim: 1048 K, a 6S pack, the pump's current at trim
    i.supply_mv = 22200
    i.pump_ma = 1800
    i.arm = 1
    n = round(seconds * p.rate_hz)
    dt = 1.0 / p.rate_hz
    t = np.arange(n) * dt
    n_pct = np.empty(n)
    nref = np.empty(n)
    v = np.empty(n)
    for k in range(n):
        sq = square(k * dt)
        i.tick = k
        i.speed_rpm = round(plant.n_pct * RPM_PER_PCT)
        i.demand_cpct = round(p.trim_n_pct * 100.0) + 100 * sq
        i.open_loop_mv = round(p.trim_v * 1000.0) + 1000 * sq
        o = ecu.tick(i)
        n_pct[k] = plant.n_pct
        nref[k] = o.nref_cpct / 100.0
        v[k] = o.pump_mv / 1000.0 if o.mode == RUN else p.trim_v
        plant.step(v[k] - p.trim_v, dt)
    o = ecu.out
    raw = (o.ap21_q24, o.ap22_q24, o.lambda_q24, o.theta21_q24, o.theta22_q24,
           o.kx1_q24, o.kx2_q24, o.kr_q24, o.kf1_q24, o.kf2_q24)  # fmt: skip
    return RunResult(t, n_pct, nref, v, {k: r / Q24 for k, r in zip(ESTIMATES, raw, strict=True)})


def run_float(p: EcuParams, seconds: float, true_rate: bool) -> RunResult:
    """The float64 twin; with ``true_rate`` it gets the plant's exact speed and rate."""
    loop = FloatLoop(p)
    plant = FastEngine()
    n = round(seconds * p.rate_hz)
    dt = 1.0 / p.rate_hz
    t = np.arange(n) * dt
    n_pct = np.empty(n)
    nref = np.empty(n)
    v = np.empty(n)
    for k in range(n):
        sq = square(k * dt)
        demand = p.trim_n_pct + sq
        v_open = p.trim_v + sq
        if true_rate:
            v[k] = loop.step(plant.n_pct, demand, v_open, plant.dn_dot)
        else:
            v[k] = loop.step(round(plant.n_pct * RPM_PER_PCT) / RPM_PER_PCT, demand, v_open)
        n_pct[k] = plant.n_pct
        nref[k] = p.trim_n_pct + loop.mrac.xm1
        plant.step(v[k] - p.trim_v, dt)
    e, m = loop.est, loop.mrac
    vals = (e.ap21, e.ap22, e.lam, e.th1, e.th2, m.kx1, m.kx2, m.kr, m.kf1, m.kf2)
    return RunResult(t, n_pct, nref, v, dict(zip(ESTIMATES, vals, strict=True)))


def _row(name: str, published: float, reached: float, tol: float, relative: bool) -> dict:
    err = abs(reached - published)
    bound = tol * abs(published) if relative else tol
    return {
        "name": name,
        "published": published,
        "reached": reached,
        "tolerance": f"{tol * 100:g} %" if relative else f"{tol:g} abs",
        "ok": bool(err <= bound),
    }


def _rms(a: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(a * a))))


def _rel(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-12)


def scenario_rows(name: str, seconds: float = 300.0) -> list[dict]:
    """Published-against-reached rows for one scenario, plus fixed-vs-float and rate-filter rows."""
    p = scenario_params(name)
    fx = run_fixed(p, seconds)
    fl = run_float(p, seconds, true_rate=False)
    tr = run_float(p, seconds, true_rate=True)
    e = fx.estimates
    rows: list[dict] = []
    tag = name.replace("sec", "sec ").replace("_", ".")
    if name == "sec4_2":
        a21, a22 = PUBLISHED["ap_row2"]
        rows.append(_row(f"{tag} A_p[2][1]", a21, e["ap21"], 0.01, True))
        rows.append(_row(f"{tag} A_p[2][2]", a22, e["ap22"], 0.01, True))
        rows.append(_row(f"{tag} Lambda", PUBLISHED["lambda"], e["lam"], 0.01, True))
    else:
        kx1, kx2 = PUBLISHED["kx_ideal"]
        rows.append(_row(f"{tag} Lambda", PUBLISHED["lambda"], e["lam"], 0.02, True))
        rows.append(_row(f"{tag} K_x[1]", kx1, e["kx1"], 0.05, True))
        rows.append(_row(f"{tag} K_x[2]", kx2, e["kx2"], 0.05, True))
        rows.append(_row(f"{tag} |K_r|", PUBLISHED["kr_ideal_abs"], abs(e["kr"]), 0.05, True))
        w = fx.t >= fx.t[-1] - TRACKING_WINDOW_S
        track = _rms(fx.n_pct[w] - fx.nref_pct[w])
        rows.append(_row(f"{tag} tracking RMS N-N_ref (%N)", 0.0, track, TRACKING_TOL_PCT, False))
    diff = _rms(fx.n_pct - fl.n_pct)
    rows.append(_row(f"{tag} fixed vs float: speed RMS (%N)", 0.0, diff, 0.05, False))
    worst = max(_rel(e[k], fl.estimates[k]) for k in ("ap21", "ap22", "lam"))
    if name == "sec5_2":
        worst = max(worst, *(_rel(e[k], fl.estimates[k]) for k in ("kx1", "kx2", "kr")))
    rows.append(_row(f"{tag} fixed vs float: worst estimate (rel.)", 0.0, worst, 0.01, False))
    # effect of the ECU's rate filter (central difference on whole rpm) against the true rate
    lam_effect = _rel(fl.estimates["lam"], tr.estimates["lam"])
    rows.append(
        {
            "name": f"{tag} rate filter effect on Lambda (rel., info)",
            "published": None,
            "reached": lam_effect,
            "tolerance": None,
            "ok": True,
        }
    )
    return rows


def verification_rows(seconds: float = 300.0) -> list[dict]:
    """All rows: sec. 4.2 then sec. 5.2."""
    return scenario_rows("sec4_2", seconds) + scenario_rows("sec5_2", seconds)


def format_table(rows: list[dict]) -> str:
    """A plain-text table of the rows."""

    def num(x: object) -> str:
        return "-" if x is None else (f"{x:.5g}" if isinstance(x, float) else str(x))

    width = max(len(r["name"]) for r in rows)
    lines = [f"{'check':<{width}}  {'published':>10}  {'reached':>10}  {'tolerance':>9}  ok"]
    for r in rows:
        lines.append(
            f"{r['name']:<{width}}  {num(r['published']):>10}  {num(r['reached']):>10}  "
            f"{num(r['tolerance']):>9}  {'yes' if r['ok'] else 'NO'}"
        )
    return "\n".join(lines)
