"""Sec. 4.2 (estimator alone) and sec. 5.2 (indirect MRAC) on the eq. 3.24 fast model, in one
process, in both readings of the document (ecu.params.READINGS).

Runs per scenario:

- ``core``: the firmware's fixed-point estimator and MRAC kernels (ecu.estimator, ecu.mrac)
  handed the plant's true state, as the document's simulation had it; the published numbers are
  checked against this run;
- ``core_float``: their float64 twins (ecu.reference) on the same true state;
- ``ecu``: the whole integer firmware (ecu.firmware.Ecu) as a microcontroller runs it: speed in
  whole rpm, rate by central difference, pump voltage in mV;
- ``ecu_float``: the float64 twin of that loop (ecu.reference.loop.FloatLoop) on the same
  quantised speed.

The inputs are the document's: sec. 4.2 a square wave of +-1 V at 0.05 Hz on the pump voltage,
sec. 5.2 a square wave of +-1 %N at 0.05 Hz on the speed command, both starting at +1.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ecu.estimator import estimator_step
from ecu.firmware import Ecu, EcuInputs
from ecu.firmware_params import compile_params
from ecu.modes import RUN
from ecu.mrac import mrac_control, mrac_gain_update, reference_model_step
from ecu.params import CTRL_MRAC, EcuParams, preset
from ecu.reference.loop import FloatLoop
from ecu.state import AP21, AP22, KF1, KF2, KR, KX1, KX2, LAM, N_THETA, TH1, TH2, EcuState
from plant.fast_model import FastEngine

Q24 = float(1 << 24)
RPM_PER_PCT = 1125.0
# the firmware's order (ecu.state); theta and K_f name their regressor, whatever the reading
ESTIMATES = (
    "ap21",
    "ap22",
    "lam",
    "th_dndv",
    "th_dn2dv",
    "kx1",
    "kx2",
    "kr",
    "kf_dndv",
    "kf_dn2dv",
)
SLOTS = (AP21, AP22, LAM, TH1, TH2, KX1, KX2, KR, KF1, KF2)

READINGS = ("printed", "reproducing")


@dataclass(frozen=True)
class Setup:
    """One scenario in one reading: its preset, the time its published results are read at, and
    the ECU rate (sec. 4.2 at the 1 ms step of the document's simulation: the estimates sit on a
    slow, lightly damped orbit that the 10 ms step moves)."""

    preset: str
    seconds: float
    rate_hz: int


SETUPS: dict[tuple[str, str], Setup] = {
    ("sec4_2", "printed"): Setup("sec4_2_estimator", 300.0, 1000),
    ("sec4_2", "reproducing"): Setup("sec4_2_estimator_reproducing", 1100.0, 1000),
    ("sec5_2", "printed"): Setup("sec5_2_mrac_fast", 300.0, 100),
    ("sec5_2", "reproducing"): Setup("sec5_2_mrac_fast_reproducing", 300.0, 100),
}
SCENARIOS = ("sec4_2", "sec5_2")


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


def scenario_params(name: str, reading: str = "printed", **overrides: object) -> EcuParams:
    """The ECU parameters of one scenario in one reading, at its stated rate."""
    if (name, reading) not in SETUPS:
        raise ValueError(
            f"unknown scenario {name!r} or reading {reading!r}; choose from "
            f"{list(SCENARIOS)} and {list(READINGS)}"
        )
    setup = SETUPS[(name, reading)]
    return preset(setup.preset, **{"rate_hz": setup.rate_hz, **overrides})


class _Histories:
    """The time histories of one run of ``seconds`` at the ECU rate of ``p``."""

    def __init__(self, p: EcuParams, seconds: float) -> None:
        n = round(seconds * p.rate_hz)
        self.dt = 1.0 / p.rate_hz
        self.ticks = range(n)
        self.t = np.arange(n) * self.dt
        self.n_pct = np.empty(n)
        self.nref = np.empty(n)
        self.v = np.empty(n)

    def result(self, values: tuple[float, ...]) -> RunResult:
        return RunResult(
            self.t, self.n_pct, self.nref, self.v, dict(zip(ESTIMATES, values, strict=True))
        )


class TruePlant(Protocol):
    """A plant as the document's simulation saw it: true speed deviation and rate out, the pump
    voltage's deviation from trim in (FastEngine, or sil.verify.aero.AeroTruth)."""

    dn_pct: float
    dn_dot: float

    @property
    def n_pct(self) -> float: ...

    def step(self, dv_volt: float, dt_s: float) -> None: ...


def run_core(p: EcuParams, seconds: float, plant: TruePlant | None = None) -> RunResult:
    """The fixed-point estimator and MRAC kernels on the plant's true state (Q7.24), in the
    order of :class:`ecu.reference.loop.FloatLoop` given true rates: each estimator interval
    ends m ticks back (m the rate window's half), so that the two runs see the same intervals.
    The plant defaults to the eq. 3.24 fast model."""
    fp = compile_params(p)
    s = EcuState()
    for k in range(N_THETA):
        s.theta_q24[k] = fp.init_theta_q24[k]
    m = fp.rate_half_window
    hist: deque[list[int]] = deque(maxlen=m + 2)  # [dN, dN', u] per tick, newest last
    plant = FastEngine() if plant is None else plant
    h = _Histories(p, seconds)
    dt = h.dt
    for k in h.ticks:
        sq = square(k * dt)
        dn = round(plant.dn_pct * Q24)
        rate = round(plant.dn_dot * Q24)
        hist.append([dn, rate, 0])
        if k == 0:
            s.xm1_q24 = dn
        if k >= 2 * m + 1:
            old, new = hist[0], hist[1]
            estimator_step(s, fp, old[0], old[1], new[0], new[1], old[2], 1)
        r = round(sq * Q24)
        if fp.controller == CTRL_MRAC:
            u = mrac_control(s, fp, dn, rate, r)
            mrac_gain_update(s, fp)
        else:
            u = round(sq * Q24)
        reference_model_step(s, fp, r)
        hist[-1][2] = u
        h.n_pct[k] = plant.n_pct
        h.nref[k] = p.trim_n_pct + s.xm1_q24 / Q24
        h.v[k] = p.trim_v + u / Q24
        plant.step(u / Q24, dt)
    return h.result(tuple(s.theta_q24[k] / Q24 for k in SLOTS))


def run_ecu(p: EcuParams, seconds: float) -> RunResult:
    """The integer firmware against the eq. 3.24 plant, seeing speed in whole rpm."""
    ecu = Ecu(p)
    plant = FastEngine()
    i = EcuInputs()
    i.egt_dk = 10480  # our plant at trim: 1048 K, a 6S pack, the pump's current at trim
    i.supply_mv = 22200
    i.pump_ma = 1800
    i.arm = 1
    h = _Histories(p, seconds)
    dt = h.dt
    for k in h.ticks:
        sq = square(k * dt)
        i.tick = k
        i.speed_rpm = round(plant.n_pct * RPM_PER_PCT)
        i.demand_cpct = round(p.trim_n_pct * 100.0) + 100 * sq
        i.open_loop_mv = round(p.trim_v * 1000.0) + 1000 * sq
        o = ecu.tick(i)
        h.n_pct[k] = plant.n_pct
        h.nref[k] = o.nref_cpct / 100.0
        h.v[k] = o.pump_mv / 1000.0 if o.mode == RUN else p.trim_v
        plant.step(h.v[k] - p.trim_v, dt)
    return h.result(tuple(ecu.s.theta_q24[k] / Q24 for k in SLOTS))


def run_float(
    p: EcuParams, seconds: float, true_rate: bool, plant: TruePlant | None = None
) -> RunResult:
    """The float64 twin; with ``true_rate`` it gets the plant's exact speed and rate (the twin
    of :func:`run_core`), without it the speed in whole rpm (the twin of :func:`run_ecu`)."""
    loop = FloatLoop(p)
    plant = FastEngine() if plant is None else plant
    h = _Histories(p, seconds)
    dt = h.dt
    for k in h.ticks:
        sq = square(k * dt)
        demand = p.trim_n_pct + sq
        v_open = p.trim_v + sq
        if true_rate:
            h.v[k] = loop.step(plant.n_pct, demand, v_open, plant.dn_dot)
        else:
            h.v[k] = loop.step(round(plant.n_pct * RPM_PER_PCT) / RPM_PER_PCT, demand, v_open)
        h.n_pct[k] = plant.n_pct
        h.nref[k] = p.trim_n_pct + loop.mrac.xm1
        plant.step(h.v[k] - p.trim_v, dt)
    e, m = loop.est, loop.mrac
    return h.result((e.ap21, e.ap22, e.lam, e.th1, e.th2, m.kx1, m.kx2, m.kr, m.kf1, m.kf2))


def rms(a: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(a * a))))
