"""The speed rate the control laws and limit loops use (ecu.rate_filter): its poles, its noise
against the central difference, its float64 twin, and what it does in the closed loop."""

from __future__ import annotations

import math
import random
import statistics
from typing import Any

import numpy as np
import pytest

from ecu.firmware_params import compile_params
from ecu.params import ParamError, preset
from ecu.rate_filter import rate_filter_start, rate_filter_step
from ecu.reference.rate_filter import FloatRateFilter
from ecu.state import EcuState
from sil.verify import fast

Q = float(1 << 24)
RPM_PER_PCT = 1125.0


def _fixed(p: Any, samples: list[float]) -> list[float]:
    """The firmware's filter over speed deviations (%N): its rate after each sample (%N/s)."""
    fw = compile_params(p)
    s = EcuState()
    out = []
    for k, x in enumerate(samples):
        dn = round(x * Q)
        if k == 0:
            rate_filter_start(s, dn)
        else:
            rate_filter_step(s, fw, dn, 0, 1)
        out.append(s.rf_v_q24 / Q)
    return out


def _matrix(f: FloatRateFilter) -> np.ndarray:
    k1, k2, k3 = f.k
    a = np.array([[1.0, f.dt, 0.0], [0.0, 1.0, f.dt], [0.0, 0.0, 1.0]])
    return a - np.outer([k1, k2, k3], [1.0, 0.0, 0.0])


@pytest.mark.parametrize("rate_hz", [50, 100, 1000])
def test_error_dynamics_have_the_triple_pole(rate_hz: int) -> None:
    p = preset("default", rate_hz=rate_hz)
    f = FloatRateFilter(p)
    z0 = math.exp(-p.rate_filter_bw / rate_hz)
    assert np.allclose(np.poly(_matrix(f)), np.poly([z0, z0, z0]), atol=1e-12)


@pytest.mark.parametrize("rate_hz", [50, 100, 1000])
def test_fixed_point_filter_follows_its_float64_twin(rate_hz: int) -> None:
    p = preset("default", rate_hz=rate_hz)
    rnd = random.Random(rate_hz)
    x, v, xs = 0.0, 0.0, []
    for _ in range(5 * rate_hz):  # a random walk in acceleration, with sensor noise
        v += rnd.gauss(0.0, 5.0) / rate_hz
        x += v / rate_hz
        xs.append(x + rnd.gauss(0.0, 0.02))
    fixed = _fixed(p, xs)
    twin = FloatRateFilter(p)
    worst = 0.0
    for k, xk in enumerate(xs):
        twin.start(xk) if k == 0 else twin.step(xk, 0.0, (0.0, 0.0, 0.0))
        worst = max(worst, abs(fixed[k] - twin.v))
    assert worst < 1e-3  # %N/s, against rates of several %N/s


def test_constant_acceleration_leaves_no_rate_error() -> None:
    p = preset("default")
    acc, hz = 3.0, p.rate_hz  # %N/s^2
    xs = [0.5 * acc * (k / hz) ** 2 for k in range(3 * hz)]
    rates = _fixed(p, xs)
    # after sample k dN-hat predicts sample k+1 and v-hat the step from k+1 to k+2, the rate of
    # their middle: acc (k + 3/2) / hz (a central difference over +-m gives that of k - m)
    assert abs(rates[-1] - acc * (len(xs) + 0.5) / hz) < 1e-4


def test_noise_is_what_the_transfer_function_says_and_far_under_the_difference() -> None:
    p = preset("default")
    f = FloatRateFilter(p)
    sigma = 0.02  # %N
    # the impulse response from a measurement to v-hat, from the filter's matrices
    m, b = _matrix(f), np.array(f.k)
    h, state = [], b.copy()
    for _ in range(2000):
        h.append(state[1])
        state = m @ state
    predicted = sigma * math.sqrt(float(np.sum(np.square(h))))
    rnd = random.Random(1)
    rates = _fixed(p, [rnd.gauss(0.0, sigma) for _ in range(20000)])
    measured = statistics.pstdev(rates[500:])
    assert abs(measured / predicted - 1.0) < 0.05, (measured, predicted)
    fw = compile_params(p)
    difference = math.sqrt(2.0) * sigma * fw.rate_hz / (2 * fw.rate_half_window)
    # at 8 rad/s a tenth of the +-2 tick difference's noise (it goes about as bw^1.5)
    assert measured < 0.12 * difference, (measured, difference)


def _noisy_run(make_rig: Any, filtered: bool, sigma_rpm: float, seconds: float) -> dict:
    """The ECU at constant demand on the fast plant, its speed reading with white noise."""
    # the fast plant is the fast model: the command lag that matches it is none
    p = preset("default", rate_filter_on=filtered, limiters_on=False, mrac_cmd_lag_s=0.0)
    rig = make_rig(params=p)
    rig.step(2)
    noise = random.Random(7)
    volts, errors = [], []
    for k in range(round(seconds * p.rate_hz)):
        rpm = round(rig.plant.n_pct * RPM_PER_PCT + noise.gauss(0.0, sigma_rpm))
        o = rig.step(1, speed_rpm=rpm)
        if k * rig.dt > 5.0:  # after the start
            volts.append(o.pump_mv / 1000.0)
            errors.append(rig.plant.n_pct - p.trim_n_pct)
    return {
        "v_std": statistics.pstdev(volts),
        "n_rms": math.sqrt(statistics.fmean(e * e for e in errors)),
        "p": p,
    }


def test_filtered_rate_keeps_the_speed_noise_off_the_pump(make_rig: Any) -> None:
    sigma = 5.0
    diff = _noisy_run(make_rig, filtered=False, sigma_rpm=sigma, seconds=25.0)
    filt = _noisy_run(make_rig, filtered=True, sigma_rpm=sigma, seconds=25.0)
    # the central difference over +-m ticks passes the noise as u = (K_x1 + c) e[k] - c e[k-2m],
    # c = K_x2 / (2 m dt): its standard deviation, independent of the loop (the plant is slow)
    fw = compile_params(diff["p"])
    kx1, kx2 = diff["p"].init_kx
    c = kx2 * fw.rate_hz / (2 * fw.rate_half_window)
    predicted = math.hypot(kx1 + c, c) * sigma / RPM_PER_PCT
    assert abs(diff["v_std"] / predicted - 1.0) < 0.2, (diff["v_std"], predicted)
    assert filt["v_std"] < 0.3 * diff["v_std"], (filt["v_std"], diff["v_std"])
    assert filt["n_rms"] < diff["n_rms"] + 0.01, (filt["n_rms"], diff["n_rms"])  # held as well


def test_filtered_rate_loop_follows_its_float64_twin() -> None:
    # the practical default (A_p commissioned, only Lambda-hat adapts) on the sec. 5.2 square
    # wave, without what the twin does not model (limit loops, dead zone, freeze)
    p = preset(
        "default", rate_filter_on=True, limiters_on=False, dead_zone_on=False, freeze_on=False
    )
    ecu = fast.run_ecu(p, 120.0)
    twin = fast.run_float(p, 120.0, true_rate=False)
    assert math.sqrt(float(((ecu.n_pct - twin.n_pct) ** 2).mean())) < 0.02  # %N
    assert math.sqrt(float(((ecu.v - twin.v) ** 2).mean())) < 0.005  # V
    for k in ("lam", "kx1", "kx2", "kr"):
        a, b = ecu.estimates[k], twin.estimates[k]
        assert abs(a - b) <= 0.01 * abs(b), k


@pytest.mark.parametrize(("rate_hz", "bw"), [(100, 1.0), (100, 60.0), (50, 16.0)])
def test_bandwidth_outside_its_range_is_refused(rate_hz: int, bw: float) -> None:
    with pytest.raises(ParamError, match="rate_filter_bw"):
        compile_params(preset("default", rate_hz=rate_hz, rate_filter_bw=bw))
