"""Fuel schedules from the plant (plant.schedules, `sil schedules`): each line's point is what it
says it is, checked on the gas path's own balances and the component maps."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from plant.aerothermal import make_model
from plant.engine import engine_rates, pump_fuel_flow, stations
from plant.schedules import (
    HEALTH_SPREAD,
    KEEP_ACCEL,
    LEAN_MARGIN,
    NDOT_MIN_PCT_S,
    RATE_MARGIN,
    SURGE_MARGIN,
    ScheduleError,
    corner_schedules,
    fleet_schedule,
    frozen_state,
    health_corners,
    line_rise_s,
    rate_at_voltage,
    schedule,
    schedule_point,
    steady_at_speed,
)
from plant.steady_line import running_line
from plant.trim import SCALE
from sil.cli import main

SPEEDS = (60.0, 90.0, 100.0)


@pytest.fixture(scope="module")
def model_and_points():
    model = make_model()
    line = running_line(model)
    return model, {n: schedule_point(model, n, line) for n in SPEEDS}


def _rates(model, x, g):
    dxdt = np.empty(4)
    engine_rates(x, g, 1.0, model, dxdt)
    return dxdt


def _frozen(model, pt, g):
    """The frozen-speed state at fuel g, from the steady state of the point's speed."""
    _, steady = steady_at_speed(model, pt.n_pct, running_line(model))
    return steady.x, frozen_state(model, steady.x, g)


def test_steady_line_is_steady_at_its_speed(model_and_points):
    model, points = model_and_points
    for n, pt in points.items():
        x, _ = _frozen(model, pt, pt.steady_fuel_kg_s)
        assert x[3] == n
        assert np.max(np.abs(_rates(model, x, pt.steady_fuel_kg_s) / SCALE)) < 1e-8
        g, _ = pump_fuel_flow(x, pt.steady_v, model)
        assert abs(g / pt.steady_fuel_kg_s - 1.0) < 1e-6  # the pump delivers it at its voltage


def test_acceleration_line_sits_on_its_limit_with_the_gas_path_balanced(model_and_points):
    model, points = model_and_points
    p = model.params
    for pt in points.values():
        _, x = _frozen(model, pt, pt.accel_fuel_kg_s)
        g = pt.accel_fuel_kg_s
        st = stations(x, g, model)
        g2, g3, g4, g6, t5 = st[0], st[1], st[2], st[3], st[6]
        # frozen speed: both plenums and the burner in balance, the shaft accelerating
        assert abs(g2 - g3) < 1e-6 * g2 and abs(g4 - g6) < 1e-6 * g4
        assert abs(g4 - g3 - g) < 1e-12
        rates = _rates(model, x, g)
        assert np.max(np.abs(rates[:3] / SCALE[:3])) < 1e-8
        assert rates[3] == pytest.approx(pt.accel_rate_pct_s) and rates[3] > 0.0
        # the limit it names is the one it sits on; the others hold
        surge_beta = np.interp(x[3], model.compressor.n_cor_pct, model.compressor.surge_beta)
        margin = surge_beta / (x[0] / p.p0_pa) - 1.0
        assert margin == pytest.approx(pt.accel_surge_margin, rel=1e-9)
        if pt.accel_limited_by == "egt":
            assert t5 == pytest.approx(1280.0, abs=1e-3) and margin >= SURGE_MARGIN
        else:
            assert pt.accel_limited_by == "surge" and t5 <= 1280.0
            assert margin == pytest.approx(SURGE_MARGIN, abs=1e-6)
        assert pump_fuel_flow(x, pt.accel_v, model)[0] == pytest.approx(g, rel=1e-6)


def test_deceleration_floor_keeps_the_lean_margin(model_and_points):
    model, points = model_and_points
    for pt in points.values():
        _, x = _frozen(model, pt, pt.decel_fuel_kg_s)
        g = pt.decel_fuel_kg_s
        g3 = stations(x, g, model)[1]
        assert g / g3 == pytest.approx((1.0 + LEAN_MARGIN) * model.params.far_lean, rel=1e-6)
        assert pt.decel_far == pytest.approx(g / g3)
        rate = _rates(model, x, g)[3]
        assert rate == pytest.approx(pt.decel_rate_pct_s) and rate < 0.0


def test_lines_are_ordered_and_rise_with_speed(model_and_points):
    _, points = model_and_points
    for pt in points.values():
        assert pt.decel_fuel_kg_s < pt.steady_fuel_kg_s < pt.accel_fuel_kg_s
        assert pt.decel_v < pt.steady_v < pt.accel_v
    lines = [[getattr(points[n], k) for n in SPEEDS] for k in ("accel_v", "steady_v", "decel_v")]
    assert all(np.all(np.diff(v) > 0) for v in lines)


def test_command_writes_its_table_and_refuses_bad_options(tmp_path, capsys):
    out = tmp_path / "sched"
    argv = ["schedules", "--speeds", "70,95", "--health-spread", "0", "--out", str(out), "--json"]
    assert main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert [p["n_pct"] for p in data["points"]] == [70.0, 95.0]
    assert data["settings"]["egt_limit_k"] == 1280.0 and data["settings"]["health_spread"] == 0
    lo, hi = data["settings"]["zero_fuel_egt_k"]  # the nominal engine's, at 70 and 95 %N
    assert 250.0 < lo <= hi < 400.0
    assert "corner_own_line_rise_s" not in data["settings"]  # idle (55 %N) is not in the table
    assert {f.name for f in out.iterdir()} == {"schedules.csv", "schedules.json", "schedules.png"}
    bads = (["--surge-margin", "1.5"], ["--speeds", "20"], ["--egt-limit", "nan"])
    for bad in (*bads, ["--health-spread", "-0.1"]):
        with pytest.raises(SystemExit) as exc:
            main(["schedules", "--out", str(out), *bad])
        assert exc.value.code == 2
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(SystemExit) as exc:
        main(["schedules", "--speeds", "70", "--out", str(blocker / "sub")])
    assert exc.value.code == 2


def test_fleet_line_holds_for_every_corner_that_runs_and_keeps_the_nominal_accelerating():
    model = make_model()
    speeds = (70.0, 100.0)
    fleet = fleet_schedule(model, speeds)
    nominal = schedule(model, speeds)
    corners = health_corners(model, HEALTH_SPREAD)
    assert len(corners) == 16
    for corner in corners:
        line = running_line(corner)
        for n, pt in zip(speeds, fleet, strict=True):
            try:
                own = schedule_point(corner, n, line)
            except ScheduleError:
                continue  # over a limit in steady state there: its EGT loop holds it lower
            assert pt.accel_v <= own.accel_v + 1e-9 or pt.accel_limited_by == "keep"
            assert pt.decel_v >= own.decel_v - 1e-9
    for pt, nom in zip(fleet, nominal, strict=True):
        assert pt.steady_v == nom.steady_v
        kept = nom.steady_v + KEEP_ACCEL * (nom.accel_v - nom.steady_v)
        assert kept - 0.05 < pt.accel_v <= nom.accel_v  # (kept in fuel, about in voltage)
        assert pt.decel_v >= nom.decel_v
    # the acceleration schedule: 1.2 times the nominal engine's rate on the fleet line, >= 5 %N/s
    for pt, nom in zip(fleet, nominal, strict=True):
        rate = rate_at_voltage(model, running_line(model), nom, pt.accel_v)
        assert 0.0 < rate < nom.accel_rate_pct_s  # a lower line: a slower nominal engine
        assert pt.accel_rate_pct_s == pytest.approx(rate)
        assert pt.ndot_pct_s == pytest.approx(max(NDOT_MIN_PCT_S, (1.0 + RATE_MARGIN) * rate))
        assert nom.ndot_pct_s == max(NDOT_MIN_PCT_S, (1.0 + RATE_MARGIN) * nom.accel_rate_pct_s)
    assert fleet[0].ndot_pct_s > 10.0 and fleet[1].ndot_pct_s == NDOT_MIN_PCT_S
    # at 70 %N a hot corner sets the line; at 100 %N the nominal's kept margin does
    assert fleet[0].accel_limited_by == "egt" and fleet[0].accel_v < nominal[0].accel_v - 0.3
    assert fleet[1].accel_limited_by == "keep"
    assert nominal[1].steady_fuel_kg_s < fleet[1].accel_fuel_kg_s < nominal[1].accel_fuel_kg_s


def test_each_corner_on_its_own_line_bounds_what_the_fleet_line_can_do():
    """Every corner's own schedule, as fleet_schedule builds on it: the points it runs at
    within the limits, each the corner's own; the nominal engine is slower on the fleet line
    than on its own, and a hot corner holds less than full speed within the EGT limit."""
    model = make_model()
    speeds = (55.0, 70.0, 85.0, 100.0)
    corners = corner_schedules(model, speeds)
    assert len(corners) == 16
    assert fleet_schedule(model, speeds, corners=corners) == fleet_schedule(model, speeds)
    engine = health_corners(model, HEALTH_SPREAD)
    for corner, (line, own) in zip(engine, corners, strict=True):
        assert [p.n_pct for p in own] == sorted(p.n_pct for p in own)
        for p in own[:: max(1, len(own) - 1)]:  # the first and the last
            assert p == schedule_point(corner, p.n_pct, line)
    tops = [own[-1].n_pct for _, own in corners if own]
    assert min(tops) < 100.0 <= max(tops)
    nominal_line = running_line(model)
    own_rise = line_rise_s(schedule(model, speeds), nominal_line)
    assert own_rise < line_rise_s(fleet_schedule(model, speeds, corners=corners), nominal_line)


def test_line_rise_is_the_integral_of_the_lines_rate():
    """Closed forms: a constant rate over a thrust linear in speed takes (N95 - idle) / rate; a
    rate linear in speed, r = a N, takes ln(N95 / idle) / a; a stalled line never gets there."""
    base = schedule_point(make_model(), 70.0, running_line(make_model()))
    speeds = np.arange(45.0, 100.1, 5.0)
    line = {"N_pct": speeds, "thrust_N": 2.0 * speeds}  # thrust 2 N per %N
    n95 = 55.0 + 0.95 * 45.0

    def points(rates):
        return [
            replace(base, n_pct=n, accel_rate_pct_s=r) for n, r in zip(speeds, rates, strict=True)
        ]

    assert line_rise_s(points(np.full(12, 8.0)), line) == pytest.approx(
        (n95 - 55.0) / 8.0, rel=1e-6
    )
    rise = line_rise_s(points(0.1 * speeds), line)
    assert rise == pytest.approx(math.log(n95 / 55.0) / 0.1, rel=1e-5)
    assert line_rise_s(points(np.where(speeds == 80.0, 0.0, 5.0)), line) == math.inf
