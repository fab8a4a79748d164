"""The gain-scheduled PI baseline: its design rule checked on the loop it gives, its linearised
plant against a numerical linearisation of eq. 3.5, its schedule and laws against their float64
twin, and the closed loop."""

from __future__ import annotations

import math
import random
from typing import Any

import numpy as np
import pytest
from scipy.optimize import brentq

from ecu.firmware_params import compile_params, pi_schedule
from ecu.params import ParamError, preset
from ecu.pi import pi_control, pi_track, scheduled
from ecu.pi_design import MIN_MARGIN_DEG, plant_response
from ecu.reference.pi import FloatPi
from ecu.state import N_THETA, PID_I, EcuState
from plant.fast_model import THETA_EQ_3_23, fast_model_derivative

Q = float(1 << 24)


def _loop(pt: Any, w: np.ndarray) -> np.ndarray:
    """C(jw) G(jw) of one scheduling point."""
    s = 1j * w
    return (pt.kp + pt.ki / s) * np.array([plant_response(pt.plant, x) for x in w])


@pytest.mark.parametrize(("bandwidth", "margin"), [(1.75, 50.0), (1.75, 60.0), (2.5, 50.0)])
def test_each_point_crosses_over_where_designed_with_its_margin(bandwidth: float, margin: float):
    for pt in pi_schedule(preset("default", pi_bandwidth=bandwidth, pi_phase_margin=margin)):
        w = np.logspace(-2, 2, 4000)
        mag = np.abs(_loop(pt, w))
        crossings = np.flatnonzero(np.diff(np.sign(mag - 1.0)))
        assert len(crossings) == 1, pt  # one crossover: |L| falls through 1 once
        wc = brentq(lambda x, pt=pt: abs(_loop(pt, np.array([x]))[0]) - 1.0, w[crossings[0]], w[-1])
        assert abs(wc / pt.wc - 1.0) < 1e-6 and pt.wc <= bandwidth + 1e-9
        pm = 180.0 + math.degrees(np.angle(_loop(pt, np.array([wc]))[0]))
        assert pm >= MIN_MARGIN_DEG - 1e-6 and abs(pm - pt.margin_deg) < 1e-6
        if pt.wc == bandwidth:  # not stepped down: the margin aimed at, unless the PI's phase
            pi_phase = -math.degrees(math.atan2(pt.ki, pt.kp * pt.wc))  # was at its -5 deg cap
            assert pm >= margin - 1e-6 or abs(pi_phase + 5.0) < 1e-6


def test_linearised_plant_matches_a_numerical_linearisation_of_eq_3_5() -> None:
    a21, a22, lam, th1, th2 = THETA_EQ_3_23
    for pt in pi_schedule(preset("default")):
        dn = pt.n_pct - 89.68
        b = lam + th1 * dn + th2 * dn * dn
        u0 = brentq(lambda u, dn=dn: fast_model_derivative(dn, 0.0, u, THETA_EQ_3_23)[1], -30, 30)
        assert abs(u0 + a21 * dn / b) < 1e-9
        h = 1e-6
        acc = lambda x, v, u: fast_model_derivative(x, v, u, THETA_EQ_3_23)[1]  # noqa: E731
        d_dn = (acc(dn + h, 0.0, u0) - acc(dn - h, 0.0, u0)) / (2 * h)
        d_v = (acc(dn, h, u0) - acc(dn, -h, u0)) / (2 * h)
        d_u = (acc(dn, 0.0, u0 + h) - acc(dn, 0.0, u0 - h)) / (2 * h)
        assert np.allclose((d_u, d_dn, d_v), pt.plant, rtol=1e-6, atol=1e-8), pt


def test_schedule_and_laws_follow_their_float64_twin() -> None:
    p = preset("default", controller="pi")
    fw = compile_params(p)
    twin = FloatPi(p)
    rnd = random.Random(3)
    for _ in range(500):
        n = rnd.uniform(50.0, 110.0)
        kp, ki = twin.gains(n)
        n_q24 = round(n * Q)
        assert abs(scheduled(fw, fw.pi_kp_q24, n_q24) / Q - kp) < 1e-6
        assert abs(scheduled(fw, fw.pi_ki_dt_q28, n_q24) / float(1 << 28) * p.rate_hz - ki) < 1e-5
    s = EcuState()
    for k in range(N_THETA):
        s.theta_q24[k] = fw.init_theta_q24[k]
    worst = 0.0
    for k in range(3000):
        n = 70.0 + 30.0 * math.sin(k / 300.0)
        e = rnd.gauss(0.0, 1.0)
        u = pi_control(s, fw, round(e * Q), round(n * Q)) / Q
        worst = max(worst, abs(u - twin.control(e, n)))
        if k % 100 == 99:  # a limit loop took over: both track the applied voltage
            pi_track(s, fw, round(e * Q), round(n * Q), round(0.5 * Q))
            twin.track(e, n, 0.5)
            assert abs(s.theta_q24[PID_I] / Q - twin.i) < 1e-5
    assert worst < 1e-4


def test_closed_loop_settles_on_demand_without_steady_state_error(make_rig: Any) -> None:
    p = preset("default", controller="pi", limiters_on=False)
    rig = make_rig(params=p)
    rig.step(2)
    rig.step(30 * p.rate_hz, demand_cpct=9200)
    assert abs(rig.plant.n_pct - 92.0) < 0.02
    peak = 0.0
    for _ in range(30 * p.rate_hz):
        rig.step(1, demand_cpct=8600)
        peak = min(peak, rig.plant.n_pct - 86.0)
    assert abs(rig.plant.n_pct - 86.0) < 0.02
    assert peak > -0.25 * 6.0  # a 50-degree loop: overshoot well under a quarter of the step


def test_a_model_with_no_input_gain_is_refused() -> None:
    with pytest.raises(ParamError, match="pi_bandwidth"):
        compile_params(preset("default", controller="pi", init_lambda=0.5, lambda_floor=0.1))
