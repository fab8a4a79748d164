"""Transients: the document's staircases (figs. 2.14-2.17, 3.2) and the least squares of
eq. 3.22 against eq. 3.23; flameout and the envelope edges."""

from __future__ import annotations

import numpy as np
import pytest

from plant import flags as fl
from plant import staircase
from plant.aerothermal import AeroThermalPlant
from plant.interface import PlantConfig

HOLD_S = 6.0


@pytest.fixture(scope="module")
def fuel_staircase(model, trim, running):
    fuels = [staircase.steady_fuel_for(running, n) for n in staircase.LEVELS_PCT]
    return staircase.run(model, trim.x, fuels, HOLD_S, pump_in_loop=False)


@pytest.fixture(scope="module")
def voltage_staircase(model, trim, running):
    volts = [staircase.steady_voltage_for(model, running, n) for n in staircase.LEVELS_PCT]
    t, x, v = staircase.run(model, trim.x, volts, 10.0, pump_in_loop=True)
    return t, x, v


def test_fuel_staircase_reaches_each_level(fuel_staircase):
    _, x, _ = fuel_staircase
    n_hold = int(HOLD_S / staircase.DT_S)
    for i, level in enumerate(staircase.LEVELS_PCT):
        assert x[(i + 1) * n_hold - 1, 3] == pytest.approx(level, abs=0.1)


@pytest.mark.parametrize("state", [0, 3])  # P3 and N: monotone, no overshoot
def test_fuel_staircase_speed_and_pressure_are_monotone_per_step(fuel_staircase, state):
    _, x, u = fuel_staircase
    n_hold = int(HOLD_S / staircase.DT_S)
    for i in range(len(staircase.LEVELS_PCT)):
        seg = x[i * n_hold : (i + 1) * n_hold, state]
        d = np.diff(seg)
        direction = np.sign(seg[-1] - seg[0])
        assert np.all(d * direction >= -1e-9 * abs(seg[0])), f"step {i} is not monotone"


@pytest.mark.parametrize("state", [1, 2])  # P5, T4: a fast jump then at most one turn (2nd order)
def test_fuel_staircase_fast_states_turn_at_most_once_per_step(fuel_staircase, state):
    _, x, _ = fuel_staircase
    n_hold = int(HOLD_S / staircase.DT_S)
    for i in range(len(staircase.LEVELS_PCT)):
        seg = x[i * n_hold : (i + 1) * n_hold, state]
        d = np.diff(seg)
        d = d[np.abs(d) > 1e-9 * abs(seg[0])]
        assert np.count_nonzero(np.diff(np.sign(d))) <= 1, f"step {i} oscillates"


def _least_squares(t, x, v, n_trim, v_trim):
    """Eq. 3.22 on eq. 3.10's regressors; N'' by differentiating the 1 ms samples."""
    dt = t[1] - t[0]
    dn = x[:, 3] - n_trim
    dv = v - v_trim
    dn1 = np.gradient(dn, dt)
    dn2 = np.gradient(dn1, dt)
    reg = np.column_stack([dn, dn1, dv, dn * dv, dn * dn * dv])
    return np.linalg.solve(reg.T @ reg, reg.T @ dn2)


def test_least_squares_gain_and_dominant_pole_against_eq_3_23(
    voltage_staircase, trim, model, running, reference
):
    """Eq. 3.23's theta is not reproduced element by element: our engine is first order in N
    with a fast burner/plenum pole, which the 5-parameter fit takes up. What is comparable
    (see the report): the steady gain alpha0 = theta2 / -theta0 and the slow (dominant) pole,
    within 30 % of the document's; the gain falls with speed (alpha1 < 0)."""
    t, x, v = voltage_staircase
    v_trim = staircase.steady_voltage_for(model, running, trim.x[3])
    theta = _least_squares(t, x, v, trim.x[3], v_trim)
    ref = reference["offline_ls_aero_thermal_eq_3_23"]
    alpha0 = theta[2] / -theta[0]
    assert alpha0 == pytest.approx(ref["alpha0"], rel=0.30)
    poles = np.roots([1.0, -theta[1], -theta[0]])
    slow = np.min(np.abs(poles))
    assert slow == pytest.approx(ref["omega_n"], rel=0.30)
    assert theta[3] < 0.0


def test_speed_gain_near_trim_is_about_two_percent_per_volt(model, trim, running):
    v0 = staircase.steady_voltage_for(model, running, trim.x[3])
    _, x_up, _ = staircase.run(model, trim.x, [v0 + 0.5], 8.0, pump_in_loop=True)
    _, x_dn, _ = staircase.run(model, trim.x, [v0 - 0.5], 8.0, pump_in_loop=True)
    gain = (x_up[-1, 3] - x_dn[-1, 3]) / 1.0
    assert 2.0 <= gain <= 3.0


def test_fuel_cut_flames_out_and_spools_down_without_nan():
    plant = AeroThermalPlant()
    n = []
    for _ in range(500):
        out = plant.step(0.0)
        n.append(out.n_pct)
        assert np.isfinite([out.p3_pa, out.p5_pa, out.t4_k, out.n_pct, out.thrust_n]).all()
    assert out.flags & fl.FLAMEOUT
    assert np.all(np.diff(n) <= 0.0)
    assert n[-1] < 30.0


def test_flameout_latches_when_fuel_returns():
    plant = AeroThermalPlant()
    for _ in range(20):
        plant.step(0.0)
    for _ in range(50):
        out = plant.step(plant.trim_duty)
    assert out.flags & fl.FLAMEOUT
    assert out.n_pct < 89.0


def test_overspeed_and_overtemperature_are_reported():
    plant = AeroThermalPlant(PlantConfig(overtemperature_egt_k=1100.0))
    assert not plant.step_fuel(0.008).flags & (fl.OVERSPEED | fl.OVERTEMPERATURE)
    for _ in range(400):
        out = plant.step_fuel(0.0135)
    assert out.flags & fl.OVERSPEED
    assert out.flags & fl.OVERTEMPERATURE
    assert out.n_pct > 100.0
