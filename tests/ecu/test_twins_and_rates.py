"""Each firmware function against its float64 twin, and the discretisation at 50-1000 Hz."""

from __future__ import annotations

import math
import random
from dataclasses import replace
from typing import Any

import pytest

from ecu.estimator import estimator_step
from ecu.firmware_params import compile_params
from ecu.mrac import command_lag, mrac_control, mrac_gain_update, reference_model_step
from ecu.params import EcuParams, preset
from ecu.pid import pid_control
from ecu.reference.estimator import FloatEstimator
from ecu.reference.mrac import FloatMrac
from ecu.reference.pid import FloatPid
from ecu.state import (
    AP21,
    AP22,
    KB,
    KF1,
    KF2,
    KR,
    KX1,
    KX2,
    LAM,
    N_THETA,
    PID_I,
    TH1,
    TH2,
    EcuState,
)
from plant.fast_model import FastEngine

Q = float(1 << 24)


def q24(x: float) -> int:
    return round(x * Q)


def fresh_state(p: EcuParams) -> tuple[Any, EcuState]:
    fw = compile_params(p)
    s = EcuState()
    for k in range(N_THETA):
        s.theta_q24[k] = fw.init_theta_q24[k]
    return fw, s


@pytest.mark.parametrize("name", ["sec4_2_estimator", "default"])
def test_estimator_matches_its_twin(name: str) -> None:
    p = replace(preset(name), dead_zone_on=False)
    fw, s = fresh_state(p)
    tw = FloatEstimator(p)
    plant = FastEngine()
    rnd = random.Random(7)
    dt = 1.0 / p.rate_hz
    u = 1.0
    x0 = (0.0, 0.0)
    for k in range(6000):
        if k % 500 == 0:
            u = rnd.uniform(-1.0, 1.0)
        plant.step(u, dt)
        x1 = (plant.dn_pct, plant.dn_dot)
        estimator_step(s, fw, q24(x0[0]), q24(x0[1]), q24(x1[0]), q24(x1[1]), q24(u), 1)
        tw.step(x0[0], x0[1], x1[0], x1[1], u, True)
        x0 = x1
    th = s.theta_q24
    pairs = ((th[AP21], tw.ap21), (th[AP22], tw.ap22), (th[LAM], tw.lam), (th[TH1], tw.th1))
    for fixed, flt in pairs:
        assert abs(fixed / Q - flt) <= 5e-3 * max(1.0, abs(flt))
    assert abs(s.xh2_q24 / Q - tw.xh2) < 1e-3


def test_lambda_floor_dead_zone_and_freeze() -> None:
    p = preset("default", lambda_floor=4.5)
    fw, s = fresh_state(p)
    # the plant's rate far under the model's with u > 0 pushes Lambda-hat down to the floor
    for _ in range(200):
        estimator_step(s, fw, 0, 0, 0, q24(-5.0), q24(2.0), 1)
    assert s.theta_q24[LAM] == q24(4.5)
    # an error inside the dead zone adapts nothing; adapt=0 adapts nothing
    before = list(s.theta_q24)
    s.xh1_q24 = s.xh2_q24 = 0
    estimator_step(s, fw, 0, 0, 0, 0, q24(0.01), 1)
    assert abs(s.e2_q24) < fw.dead_zone_q24 and list(s.theta_q24) == before
    estimator_step(s, fw, 0, 0, 0, q24(5.0), q24(2.0), 0)
    assert list(s.theta_q24) == before


@pytest.mark.parametrize("name", ["sec5_2_mrac_fast", "default"])  # default: K_b, pump scaling
def test_mrac_control_gain_update_and_reference_model_match_twins(name: str) -> None:
    p = preset(name)
    fw, s = fresh_state(p)
    tw = FloatMrac(p)
    est = FloatEstimator(p)
    rnd = random.Random(3)
    for k in range(3000):
        if k % 300 == 0:  # the estimator's outputs, held for a while
            est.ap21, est.ap22 = rnd.uniform(-3, -1), rnd.uniform(-3, -1)
            est.lam, est.th1, est.th2 = rnd.uniform(2, 6), rnd.uniform(-0.3, 0), 1e-4
            for i, v in ((AP21, est.ap21), (AP22, est.ap22), (LAM, est.lam), (TH1, est.th1),
                         (TH2, est.th2)):  # fmt: skip
                s.theta_q24[i] = q24(v)
        mrac_gain_update(s, fw)
        tw.gain_update(est)
        r = rnd.choice((-1.0, 1.0))
        reference_model_step(s, fw, q24(r))
        tw.reference_step(r)
        dn, dv = rnd.uniform(-3, 3), rnd.uniform(-5, 5)
        assert abs(mrac_control(s, fw, q24(dn), q24(dv), q24(r)) / Q - tw.control(dn, dv, r)) < 1e-4
    gains = ((KX1, tw.kx1), (KX2, tw.kx2), (KR, tw.kr), (KF1, tw.kf1), (KF2, tw.kf2), (KB, tw.kb))
    for i, v in gains:
        assert abs(s.theta_q24[i] / Q - v) < 1e-4
    assert (abs(tw.kb) > 0.1) == p.pump_scaling_on  # the bias gain moved with Lambda-hat
    assert abs(s.xm1_q24 / Q - tw.xm1) < 1e-5


@pytest.mark.parametrize("rate_hz", [50, 100, 1000])
def test_reference_model_step_response_is_right_at_every_rate(rate_hz: int) -> None:
    p = preset("default", rate_hz=rate_hz)
    fw, s = fresh_state(p)
    w = p.ref_wn
    for k in range(1, rate_hz + 1):  # 1 s of a unit step
        reference_model_step(s, fw, q24(1.0))
        t = k / rate_hz
        exact = 1.0 - (1.0 + w * t) * math.exp(-w * t)  # critically damped, eq. 5.18-5.19
        assert abs(s.xm1_q24 / Q - exact) < 0.01 * (50.0 / rate_hz) ** 2 + 1e-5


@pytest.mark.parametrize("rate_hz", [50, 1000])
def test_pid_integrator_is_exact_for_constant_error(rate_hz: int) -> None:
    p = preset("default", rate_hz=rate_hz, controller="pid")
    fw, s = fresh_state(p)
    tw = FloatPid(p)
    for _ in range(rate_hz):  # 1 s at an error of 0.5 %N
        u = pid_control(s, fw, q24(0.5), 0)
        ut = tw.control(0.5, 0.0)
    assert abs(s.theta_q24[PID_I] / Q - p.pid_ki * 0.5) < 1e-6
    assert abs(u / Q - ut) < 1e-5


@pytest.mark.parametrize("rate_hz", [50, 100, 1000])
def test_closed_loop_tracks_the_reference_model_at_every_rate(make_rig: Any, rate_hz: int) -> None:
    # the fast plant is the fast model: the command lag that matches it is none
    rig = make_rig(params=preset("default", rate_hz=rate_hz, limiters_on=False, mrac_cmd_lag_s=0.0))
    rig.step(2)
    err2 = 0.0
    n = 0
    for k in range(12 * rate_hz):
        o = rig.step(1, demand_cpct=9100 if k < 6 * rate_hz else 8800)
        err2 += (rig.plant.n_pct - o.nref_cpct / 100.0) ** 2
        n += 1
    assert math.sqrt(err2 / n) < 0.05  # %N RMS, plant against the reference model
    assert abs(rig.plant.n_pct - 88.0) < 0.02 and rig.out.sat_events == 0


@pytest.mark.parametrize("tau", [0.0, 0.55])
def test_the_mracs_command_lag_is_a_first_order_lag(tau: float) -> None:
    """command_lag (ecu.mrac): u passes unchanged without a lag; with one, a step reaches
    1 - 1/e of its size after tau (backward Euler, within a tick)."""
    p = compile_params(preset("default", mrac_cmd_lag_s=tau))
    s = EcuState()
    step = round(2.0 * (1 << 24))  # 2 V
    out = [command_lag(s, p, step) for _ in range(200)]
    if tau == 0.0:
        assert out[0] == step
        return
    k63 = next(k for k, u in enumerate(out) if u >= step * (1.0 - math.exp(-1.0)))
    assert abs((k63 + 1) * 0.01 - tau) <= 0.011
    assert abs(out[-1] - step) < step * math.exp(-2.0 / tau / 1.05)  # still closing, no overshoot
