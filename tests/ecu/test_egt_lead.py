"""The EGT limiter's lead on the thermocouple: the fixed-point filter against its float64 twin,
exact in steady state and off when asked, and the gas temperature it recovers through a probe
with the commissioned time constant; in closed loop the gas overshoots the limit less, and a
transient allowance lets it pass the limit only while the probe still reads under it."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from ecu.firmware_params import compile_params
from ecu.limiters import egt_lead_step
from ecu.params import EcuParams
from ecu.state import EcuState

DT = 0.01


def probe(gas_k: np.ndarray, tau_s: float, seed: int = 0, noise_k: float = 1.0) -> np.ndarray:
    """Thermocouple readings [0.1 K]: the gas through an exact discrete first-order lag, noise,
    rounded to the signal's 0.1 K."""
    a = 1.0 - math.exp(-DT / tau_s)
    y, out = gas_k[0], np.empty_like(gas_k)
    for k, g in enumerate(gas_k):
        y += a * (g - y)
        out[k] = y
    out += np.random.default_rng(seed).normal(0.0, noise_k, out.size)
    return np.round(out * 10.0).astype(np.int64)


def lead_fixed(p: EcuParams, readings_dk: np.ndarray) -> np.ndarray:
    fp, s = compile_params(p), EcuState()
    out = np.empty(readings_dk.size)
    for k, x in enumerate(readings_dk.tolist()):
        egt_lead_step(s, fp, x)
        s.egt_dk = x
        out[k] = s.egt_lead_q12 / 4096.0 / 10.0  # K
    return out


def lead_float(p: EcuParams, readings_dk: np.ndarray) -> np.ndarray:
    """Twin: (T_tc s + 1)/(T_f s + 1) by backward Euler in float64."""
    x = readings_dk / 10.0
    c_f = DT / (p.egt_lead_filter_s + DT)
    c_tc = p.egt_lead_tau_s / (p.egt_lead_filter_s + DT)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, x.size):
        y[k] = y[k - 1] + c_f * (x[k] - y[k - 1]) + c_tc * (x[k] - x[k - 1])
    return y


def gas_profile() -> np.ndarray:
    t = np.arange(0.0, 6.0, DT)
    gas = np.full(t.size, 1100.0)
    gas[t >= 1.0] = 1300.0  # a step
    ramp = (t >= 3.0) & (t < 4.0)
    gas[ramp] = 1300.0 - 150.0 * (t[ramp] - 3.0)  # a ramp down
    gas[t >= 4.0] = 1150.0
    return gas


def test_fixed_point_lead_matches_its_float64_twin() -> None:
    p = EcuParams()
    readings = probe(gas_profile(), p.egt_lead_tau_s, seed=1)
    fixed, twin = lead_fixed(p, readings), lead_float(p, readings)
    assert np.max(np.abs(fixed - twin)) < 0.05  # K, over 600 noisy ticks


def test_lead_recovers_the_gas_temperature_through_the_probe_lag() -> None:
    p = EcuParams()
    gas = gas_profile()
    readings = probe(gas, p.egt_lead_tau_s, noise_k=0.0)
    y, raw = lead_fixed(p, readings), readings / 10.0
    # what is left is the lead's own filter: the gas through 1/(T_f s + 1)
    seen = lead_float(replace(p, egt_lead_tau_s=0.0), np.round(gas * 10.0))
    after = int(round((1.0 + 0.3) / DT))  # 0.3 s after the 200 K step
    assert gas[after] - raw[after] > 80.0  # the probe is still far behind ...
    assert abs(y[after] - seen[after]) < 2.0  # ... the lead is where its filter lets it be
    assert np.max(np.abs(y - seen)) < 0.05 * 200.0  # everywhere, within 5 % of the step
    ramp = int(round(3.8 / DT))
    assert abs(y[ramp] - gas[ramp]) < 20.0 < abs(raw[ramp] - gas[ramp])  # a ramp: lag removed
    noisy = lead_fixed(p, probe(gas, p.egt_lead_tau_s, seed=2))
    quiet = slice(int(5.0 / DT), None)  # steady: the lead's gain on 1 K of white probe noise
    assert 1.0 < np.std(noisy[quiet]) < 6.0


def test_steady_reading_is_exact_and_the_lead_can_be_switched_off() -> None:
    flat = np.full(200, 11_234, dtype=np.int64)
    assert np.all(lead_fixed(EcuParams(), flat) * 10.0 == 11_234.0)
    off = replace(EcuParams(), egt_lead_tau_s=0.0, egt_lead_filter_s=0.0)
    readings = probe(gas_profile(), 0.5, seed=3)
    assert np.array_equal(lead_fixed(off, readings) * 10.0, readings.astype(float))


def test_the_gas_overshoots_the_egt_limit_less_with_the_lead(make_rig: Any) -> None:
    # the rig's EGT follows the speed alone, so the EGT line is off and the loop is the only
    # protection: engaged from before the step (100 K band, the engine starts 82 K under), the
    # lead lets it see the gas coming; joining it at 50 K (the default) it is too late for either
    def peak_gas(p: EcuParams) -> float:
        rig = make_rig(params=p, hot_k=150.0)  # 150 K hotter: the limit is met near 90 %N
        rig.step(300)
        peak = 0.0
        for _ in range(800):
            rig.step(1, demand_cpct=9500)
            peak = max(peak, rig.egt_steady())
        return peak

    wide = make_rig().params
    with_lead = peak_gas(wide)
    without = peak_gas(replace(wide, egt_lead_tau_s=0.0, egt_lead_filter_s=0.0))
    assert without - 1280.0 > 2.0 * (with_lead - 1280.0) > 0.0
    late = peak_gas(replace(wide, egt_engage_k=EcuParams().egt_engage_k))
    assert late - 1280.0 > 2.0 * (with_lead - 1280.0)


def test_a_transient_allowance_lets_the_gas_pass_the_limit_while_the_probe_reads_under_it(
    make_rig: Any,
) -> None:
    rig_params = make_rig().params

    def fly(margin_k: float) -> tuple[float, float, float, float]:
        """Peak gas, peak probe, time to 94 %N (s), final speed."""
        rig = make_rig(params=replace(rig_params, egt_gas_margin_k=margin_k), hot_k=150.0)
        rig.step(300)
        gas, probe, speed = [], [], []
        for _ in range(1500):
            rig.step(1, demand_cpct=9500)
            gas.append(rig.egt_steady())
            probe.append(rig.egt_k)
            speed.append(rig.plant.n_pct)
        return (
            max(gas),
            max(probe),
            rig.dt * next(k for k, n in enumerate(speed) if n >= 94.0),
            speed[-1],
        )

    held, allowed = fly(0.0), fly(30.0)
    assert held[0] < 1280.0 + 10.0  # without one the gas is held at the limit
    assert 1280.0 + 15.0 < allowed[0] < 1280.0 + 30.0 + 5.0  # it used the allowance, no more
    assert allowed[1] < allowed[0]  # the probe lags the gas
    assert allowed[2] < held[2] - 0.3  # the engine gets there sooner ...
    assert abs(allowed[3] - held[3]) < 0.1  # ... to the same steady speed within the limit


def test_the_transient_allowance_is_checked() -> None:
    from ecu.params import ParamError, validate

    validate(replace(EcuParams(), egt_gas_margin_k=50.0))
    for bad in (-1.0, EcuParams().egt_max_k - EcuParams().egt_limit_k + 1.0):
        with pytest.raises(ParamError, match="egt_gas_margin_k"):
            validate(replace(EcuParams(), egt_gas_margin_k=bad))


def test_an_open_thermocouple_does_not_saturate_the_lead() -> None:
    """A full-scale jump (an open circuit reads 16383) and back, at the largest lead allowed:
    the lead's output stays within its Q12 word, so no store saturates."""
    from ecu.fixedpoint import take_sat_events

    p = replace(EcuParams(), egt_lead_tau_s=5.0, egt_lead_filter_s=0.25)  # gain 20
    readings = np.array([1000] * 10 + [16_383] * 5 + [0] * 5 + [11_000] * 10, dtype=np.int64)
    take_sat_events()
    y = lead_fixed(p, readings)
    assert take_sat_events() == 0
    assert y.max() > 1638.3 * 15 and y.min() < -1638.3 * 3  # the lead did swing that far


def test_the_limit_holds_while_the_probe_reads_over_it_though_the_gas_cools(rig: Any) -> None:
    """The hotter of the probe and the gas is held to the limit: a reading falling fast (the lead
    under the limit) but still over it keeps the EGT loop on the probe's error, which shrinks by
    the reading's fall alone (the lead's error would have turned positive and raised the fuel)."""
    from ecu.limiters import OWNER_EGT

    p = EcuParams()
    limit_dk = round(p.egt_limit_k * 10)
    owners = [rig.step(1, demand_cpct=9500, egt_dk=limit_dk + 200).owner for _ in range(100)]
    assert owners[-1] == OWNER_EGT
    v_before = rig.out.pump_mv / 1000.0
    for k in range(1, 11):  # 150 K/s down to 5 K over the limit
        reading = limit_dk + 200 - 15 * k
        o = rig.step(1, demand_cpct=9500, egt_dk=reading)
        assert (rig.ecu.s.egt_lead_q12 >> 12) < reading  # the lead sees the gas cooling ...
        assert o.owner == OWNER_EGT
    assert (rig.ecu.s.egt_lead_q12 >> 12) < limit_dk  # ... under the limit
    # the loop's proportional part follows the probe's 15 K: Kp 15 K, less its integral
    assert o.pump_mv / 1000.0 - v_before < 1.2 * p.egt_kp * 15.0


def test_the_egt_loop_cannot_be_engaged_beyond_its_error_clamp() -> None:
    from ecu.params import EGT_ERROR_MAX_K, ParamError, validate

    validate(replace(EcuParams(), egt_engage_k=EGT_ERROR_MAX_K))
    with pytest.raises(ParamError, match="egt_engage_k"):
        validate(replace(EcuParams(), egt_engage_k=EGT_ERROR_MAX_K + 5.0))
