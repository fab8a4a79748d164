"""The fuel schedules in the firmware: the acceleration line caps the pump command from the first
tick, the deceleration floor holds it up, both move with the estimated pump and the inlet
temperature; their defaults are what `sil schedules` derives from the plant."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from ecu.firmware_params import compile_params
from ecu.limiters import OWNER_ACCEL, OWNER_DECEL, OWNER_SPEED, schedule_v, select_voltage
from ecu.params import SCHED_N0_PCT, SCHED_POINTS, SCHED_STEP_PCT, EcuParams, ParamError, preset
from ecu.state import LAM, EcuState
from plant.aerothermal import make_model
from plant.schedules import fleet_schedule

Q = float(1 << 24)
SPEEDS = SCHED_N0_PCT + SCHED_STEP_PCT * np.arange(SCHED_POINTS)


def _expected(p: EcuParams, table: tuple[float, ...], n: float, lam: float) -> float:
    """The schedule's voltage by its definition, in floats: the line moves within
    schedule_pump_range (Lambda-hat in [lo, hi]), the floor only up (in [lo, Lambda_c])."""
    v = float(np.interp(n * math.sqrt(288.15 / p.inlet_temp_k), SPEEDS, table))
    lo, hi = (r * p.lambda_commissioned for r in p.schedule_pump_range)
    if table is p.decel_floor_v:
        hi = p.lambda_commissioned
    return p.pump_dead_v + (v - p.pump_dead_v) * p.lambda_commissioned / min(max(lam, lo), hi)


def test_defaults_are_what_the_plant_allows_its_fleet() -> None:
    p = EcuParams()
    speeds = tuple(float(SPEEDS[k]) for k in (1, 6, 11))  # 50, 75 and 100 %N
    fleet = fleet_schedule(make_model(), speeds, egt_limit_k=p.egt_limit_k)
    for k, pt in zip((1, 6, 11), fleet, strict=True):
        assert abs(pt.accel_v - p.accel_line_v[k]) < 0.006
        assert abs(pt.decel_v - p.decel_floor_v[k]) < 0.006
        assert abs(pt.ndot_pct_s - p.accel_rate_pct_s[k]) < 0.06


@pytest.mark.parametrize(
    ("inlet_k", "lam_ratio"), [(288.15, 1.0), (318.0, 0.8), (253.0, 1.2), (288.15, 0.2)]
)
def test_schedule_voltage_follows_its_definition(inlet_k: float, lam_ratio: float) -> None:
    p = preset("default", inlet_temp_k=inlet_k)
    fw = compile_params(p)
    s = EcuState()
    s.ncor_k_q24 = fw.ncor_k_q24
    s.theta_q24[LAM] = round(p.lambda_commissioned * lam_ratio * Q)
    lam = s.theta_q24[LAM] / Q
    for n in np.linspace(30.0, 110.0, 81):
        for table, raw, lo, hi in (
            (p.accel_line_v, fw.accel_line_q24, fw.sched_lam_lo_q24, fw.sched_lam_hi_q24),
            (p.decel_floor_v, fw.decel_floor_q24, fw.sched_lam_lo_q24, fw.lambda_comm_q24),
        ):
            got = schedule_v(s, fw, raw, round(n * Q), lo, hi) / Q
            assert abs(got - _expected(p, table, n, lam)) < 1e-5, (n, table is p.accel_line_v)


def _step_run(make_rig: Any, schedules: bool, demand_cpct: int, ticks: int) -> list[tuple]:
    p = preset("default", fuel_schedules_on=schedules, accel_max_pct_s=100.0, decel_max_pct_s=100.0)
    rig = make_rig(params=p)
    rig.step(2)
    rows = []
    for _ in range(ticks):
        n = rig.plant.n_pct  # the speed the ECU sees this tick (to within an rpm)
        o = rig.step(1, demand_cpct=demand_cpct)
        lam = rig.ecu.s.theta_q24[LAM] / Q
        rows.append((n, o.pump_mv / 1000.0, o.owner, lam))
    return rows


def test_acceleration_line_caps_a_large_step_from_the_first_tick(make_rig: Any) -> None:
    p = EcuParams()
    capped = _step_run(make_rig, True, 10000, 300)
    free = _step_run(make_rig, False, 10000, 300)
    over = [v - _expected(p, p.accel_line_v, n, lam) for n, v, _, lam in capped]
    assert max(over) < 0.002  # V: the line holds on every tick (the slew may keep it lower)
    assert any(o == OWNER_ACCEL for _, _, o, _ in capped[:5])  # from the first ticks
    assert max(v - _expected(p, p.accel_line_v, n, lam) for n, v, _, lam in free) > 1.0


def test_deceleration_floor_holds_a_large_cut(make_rig: Any) -> None:
    p = EcuParams()
    held = _step_run(make_rig, True, 3500, 300)
    free = _step_run(make_rig, False, 3500, 300)
    under = [_expected(p, p.decel_floor_v, n, lam) - v for n, v, _, lam in held]
    assert max(under) < 0.002
    assert any(o == OWNER_DECEL for _, _, o, _ in held)
    assert max(_expected(p, p.decel_floor_v, n, lam) - v for n, v, _, lam in free) > 1.0


class _WeakPump:
    """The rig's plant behind a pump delivering `gain` times the commissioned pump's fuel."""

    def __init__(self, rig: Any, gain: float) -> None:
        self.plant, self.gain, self.p = rig.plant, gain, rig.params
        self.n_pct = rig.plant.n_pct

    def step(self, u: float, dt: float) -> None:
        v_d, trim = self.p.pump_dead_v, self.p.trim_v
        self.plant.step(self.gain * (u + trim - v_d) - (trim - v_d), dt)
        self.n_pct = self.plant.n_pct


@pytest.mark.parametrize("scaling", [True, False])
def test_a_weak_pump_the_line_holds_is_learnt_and_the_line_rises_with_it(
    make_rig: Any, scaling: bool
) -> None:
    """The estimator learns on while the acceleration line owns the command: with pump scaling
    the line delivers its fuel with the pump as learnt and the engine reaches its demand;
    without, the commissioned pump's line holds the weak one under it."""
    p = EcuParams()
    rig = make_rig(params=replace(make_rig().params, pump_scaling_on=scaling))
    rig.plant = _WeakPump(rig, 0.85)
    rig.step(1000)
    owners = [rig.step(1, demand_cpct=9500).owner for _ in range(3000)]
    lam = rig.ecu.s.theta_q24[LAM] / Q
    if scaling:
        assert lam == pytest.approx(0.85 * p.lambda_commissioned, rel=0.03)
        assert rig.plant.n_pct == pytest.approx(95.0, abs=0.1)
        assert owners[-1] == OWNER_SPEED
    else:
        assert rig.plant.n_pct < 94.0 and owners[-1] == OWNER_ACCEL


@pytest.mark.parametrize("n", [50.0, 72.5, 97.5])
def test_rate_loop_holds_the_acceleration_under_its_schedule(n: float) -> None:
    p = EcuParams()
    allowed = float(np.interp(n, SPEEDS, p.accel_rate_pct_s))  # (a standard day: Nc = N)
    for schedules_on, rate, owner in (
        (True, allowed + 1.0, OWNER_ACCEL),  # over the schedule: the rate loop cuts the fuel
        (True, allowed - 0.5, OWNER_SPEED),  # under it, and in its band: it tracks
        (False, allowed + 1.0, OWNER_SPEED),  # without schedules, only accel_max_pct_s holds
        (False, p.accel_max_pct_s + 1.0, OWNER_ACCEL),
    ):
        fw = compile_params(replace(p, fuel_schedules_on=schedules_on))
        s = EcuState()
        s.ncor_k_q24 = fw.ncor_k_q24
        v_start = float(np.interp(n, SPEEDS, p.accel_line_v)) - 1.0  # under the line
        v = int(v_start * Q)
        s.v_applied_q24 = v
        s.theta_q24[LAM] = fw.lambda_comm_q24
        s.acc_e_prev_q24 = int((p.accel_max_pct_s - rate) * Q)  # no step in the rate's margin
        if schedules_on:
            s.acc_e_prev_q24 = int((allowed - rate) * Q)
        got = select_voltage(s, fw, v, int(500 * Q), 1, int(n * Q), int(rate * Q))
        assert s.owner == owner, (schedules_on, rate)
        if owner == OWNER_ACCEL:  # its integrator alone: V - Ki dt (rate - allowed)
            over = rate - (allowed if schedules_on else p.accel_max_pct_s)
            assert got / Q == pytest.approx(v_start - p.rate_ki * fw.dt_q24 / Q * over, abs=2e-4)


@pytest.mark.parametrize(
    ("field", "value", "why"),
    [
        ("accel_rate_pct_s", (10.0,) * 11, "needs 12 values"),
        ("accel_rate_pct_s", (10.0,) * 11 + (0.1,), "0.5-100 %N/s"),
        ("accel_line_v", (10.0,) * 11, "needs 12 values"),
        ("accel_line_v", (10.0,) * 11 + (9.0,), "must not fall"),
        ("decel_floor_v", (11.0,) * 12, "under accel_line_v"),
        ("accel_line_v", (10.0,) * 11 + (math.nan,), "not finite"),
        ("inlet_temp_k", 400.0, "223-333 K"),
        ("schedule_pump_range", (1.1, 1.3), "low <= 1"),
    ],
)
def test_bad_schedules_are_refused_naming_the_field(field: str, value: Any, why: str) -> None:
    p = replace(EcuParams(), accel_line_v=(10.0,) * 12, decel_floor_v=(3.0,) * 12)
    with pytest.raises(ParamError, match=field) as exc:
        compile_params(replace(p, **{field: value}))
    assert why in str(exc.value)
