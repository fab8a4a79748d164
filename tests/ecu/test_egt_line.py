"""The EGT line: each engine's own EGT-limited acceleration line at its present speed, from the
gas estimate and the applied voltage (ecu.limiters.egt_line_v). Its basis is physics (the gas at
frozen speed rises linearly with the pump's voltage over its dead voltage, from an intercept
`sil schedules` derives), its arithmetic has a float64 twin, and on the aero-thermal plant it
holds the engines the fleet's open-loop line over-fuels (a hot engine with a strong pump)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ecu.firmware_params import compile_params
from ecu.limiters import egt_line_v
from ecu.params import EcuParams, ParamError, validate
from ecu.state import EcuState
from plant import schedules
from plant.aerothermal import make_model
from plant.schedules import _stations, frozen_state, steady_at_speed
from plant.steady_line import running_line

Q = float(1 << 24)


def test_the_gas_rises_linearly_with_the_pump_at_frozen_speed() -> None:
    """Midway between the steady state and the acceleration line, the frozen-speed EGT lies
    within a few kelvin of the straight line through the two (a rise of 300-500 K)."""
    model = make_model()
    line = running_line(model)
    for n in (55.0, 85.0):
        pt = schedules.schedule_point(model, n, line)
        _, steady = steady_at_speed(model, n, line)
        g = 0.5 * (pt.steady_fuel_kg_s + pt.accel_fuel_kg_s)
        x = frozen_state(model, steady.x, g)
        egt, v = _stations(model, x, g).t5, schedules.pump_voltage_for(model, x, g)
        straight = pt.steady_egt_k + (pt.accel_egt_k - pt.steady_egt_k) * (
            (v - pt.steady_v) / (pt.accel_v - pt.steady_v)
        )
        assert pt.accel_egt_k - pt.steady_egt_k > 300.0
        assert abs(egt - straight) < 5.0


def test_the_default_intercept_is_the_lowest_the_fleet_has() -> None:
    """egt_zero_fuel_k at or under every engine's intercept (a lower one, a lower line: safe),
    and not far under the lowest (a line needlessly low)."""
    p = EcuParams()
    model = make_model()
    speeds = (55.0, 95.0)
    points = schedules.schedule(model, speeds)
    points += [q for _, own in schedules.corner_schedules(model, speeds) for q in own]
    t0 = [schedules.zero_fuel_egt_k(q, p.pump_dead_v) for q in points]
    assert p.egt_zero_fuel_k <= min(t0) < p.egt_zero_fuel_k + 5.0
    assert max(t0) - min(t0) > 40.0  # engines differ: the lowest is the safe choice


@settings(max_examples=300, deadline=None)
@given(
    vf=st.floats(0.0, 25.0),
    gas=st.floats(250.0, 1400.0),
    t0=st.sampled_from([0.0, 250.0, 290.0, 360.0]),
    limit=st.sampled_from([1060.0, 1280.0]),
)
def test_the_fixed_point_line_matches_its_float64_twin(
    vf: float, gas: float, t0: float, limit: float
) -> None:
    p = replace(EcuParams(), egt_zero_fuel_k=t0, egt_limit_k=limit)
    fw = compile_params(p)
    s = EcuState()
    s.egt_vf_q24 = round(vf * Q)
    s.egt_lead_q12 = round(gas * 10.0) << 12
    got = egt_line_v(s, fw, s.egt_vf_q24)  # V_f at rest: the applied voltage is V_f
    assert s.egt_vf_q24 == round(vf * Q)
    # the twin on the inputs as the firmware holds them (volts in Q24, kelvin in 0.1 K)
    vd, vf = fw.pump_dead_q24 / Q, s.egt_vf_q24 / Q
    gas, t0, limit = round(gas * 10.0) / 10.0, fw.egt_zero_fuel_dk / 10.0, fw.egt_limit_dk / 10.0
    if t0 == 0.0 or 4.0 * (gas - t0) < limit - t0 or vf <= vd:
        assert got is None
        return
    want = vd + (vf - vd) * (limit - t0) / (gas - t0)
    assert got is not None and abs(got / Q - want) <= 1.0 / Q  # one LSB: the truncated division


def test_v_f_follows_the_applied_voltage_through_the_gas_estimates_lag() -> None:
    p = EcuParams()
    fw = compile_params(p)
    s = EcuState()
    s.egt_lead_q12 = 1000 << 12
    dt = 1.0 / p.rate_hz
    ticks = round(p.egt_lead_filter_s / dt)
    for _ in range(ticks):
        egt_line_v(s, fw, round(5.0 * Q))
    # backward Euler of 1 / (T_f s + 1): (1 - dt / (T_f + dt))^k after k ticks of a unit step
    assert s.egt_vf_q24 / Q == pytest.approx(5.0 * (1.0 - (1.0 - dt / (0.1 + dt)) ** ticks), 1e-4)


def test_the_intercept_is_checked() -> None:
    validate(replace(EcuParams(), egt_zero_fuel_k=0.0))
    for bad in (100.0, EcuParams().egt_limit_k - 250.0):
        with pytest.raises(ParamError, match="egt_zero_fuel_k"):
            validate(replace(EcuParams(), egt_zero_fuel_k=bad))


SCENARIO = Path(__file__).parents[2] / "sil" / "scenario" / "library" / "accel-idle-to-max.toml"
# a hot engine of the transients campaign with a pump 17 % stronger than the commissioned one
HOT_STRONG = """
initial_egt_max_K = 1280
compressor_efficiency = 0.969
compressor_flow = 0.989
pump_gain = 1.169
turbine_efficiency = 0.964
turbine_flow = 0.968
"""


@pytest.mark.parametrize("kind", ["mrac", "pid"])
def test_the_egt_line_holds_a_hot_engine_with_a_strong_pump(kind: str) -> None:
    """The fleet's line, in the commissioned pump's volts, gives this engine 17 % more fuel
    than it means; the EGT loop alone lets the gas over the limit in the idle step (about 90 K
    with the MRAC, 18 K with the PID), the EGT line holds it there (the true gas)."""
    from sil import scenario as scenarios
    from sil.campaign.case import run_case
    from sil.campaign.invariants import transient

    text = SCENARIO.read_text().replace(
        "initial_speed_pct = 55\n", f"initial_speed_pct = 55{HOT_STRONG}"
    )
    text = text.replace('kind = "mrac"', f'kind = "{kind}"')

    def overshoot(t0: float) -> float:
        case = text.replace(
            "fuel_schedules_on = 1 }", f"fuel_schedules_on = 1, egt_zero_fuel_k = {t0:g} }}"
        )
        s = scenarios.parse(case, "hot-strong", SCENARIO.parent)
        return transient(run_case(s))["egt_overshoot_K"]

    without, with_line = overshoot(0.0), overshoot(EcuParams().egt_zero_fuel_k)
    assert without > 15.0  # over the campaign's invariant (limit + 10 K)
    assert with_line < 2.0
