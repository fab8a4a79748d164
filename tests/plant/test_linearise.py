"""The linearised engine against the nonlinear one: the steady gain against two steady states a
small voltage step apart, the slow pole against a simulated small step's 63 % time."""

from __future__ import annotations

import numpy as np
import pytest

from plant.aerothermal import make_model
from plant.engine import advance_pump
from plant.fast_model import rate_per_volt
from plant.linearise import linearise, linearise_at_speed, pump_voltage_for, speed_rate_per_volt
from plant.trim import solve_steady

TRIM_FUEL = 0.008
DV = 0.05  # V: small enough for the linearisation, large against the solver's tolerance


@pytest.fixture(scope="module")
def model():
    return make_model()


@pytest.fixture(scope="module")
def trim(model):
    steady = solve_steady(model, TRIM_FUEL)
    return steady, linearise(model, steady, TRIM_FUEL)


def _settle(model, x: np.ndarray, v: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Speed every ms for ``seconds`` at pump voltage v, from x."""
    x = x.copy()
    work = np.empty((5, 4))
    n = np.empty(round(seconds * 1000))
    for k in range(n.size):
        advance_pump(x, v, 1.0, 1, 0.001, model, work)
        n[k] = x[3]
    return x, n


def test_the_trim_voltage_delivers_the_trim_fuel(model, trim):
    steady, lin = trim
    assert lin.pump_v == pytest.approx(pump_voltage_for(model, steady.x, TRIM_FUEL), abs=1e-9)
    x, n = _settle(model, steady.x, lin.pump_v, 2.0)
    assert abs(n[-1] - steady.x[3]) < 1e-3  # it holds the trim


def test_gain_and_slow_pole_match_the_nonlinear_engine(model, trim):
    steady, lin = trim
    _, n = _settle(model, steady.x, lin.pump_v + DV, 15.0)
    gain = (n[-1] - steady.x[3]) / DV
    assert gain == pytest.approx(lin.gain_pct_per_v, rel=0.03)
    t63 = (np.argmax(n - steady.x[3] >= 0.632 * (n[-1] - steady.x[3])) + 1) / 1000.0
    assert t63 == pytest.approx(lin.tau_s, rel=0.05)  # one slow pole: a first-order step
    slow, *fast = lin.poles
    assert slow.imag == 0.0 and all(abs(p) > 40.0 * abs(slow) for p in fast)


def test_at_speed_finds_its_steady_state(model):
    lin = linearise_at_speed(model, 92.0)
    x = solve_steady(model, 0.0088).x
    assert 0.5 < lin.tau_s < 1.5 and lin.gain_pct_per_v > 0.0
    assert lin.pump_v > pump_voltage_for(model, x, 0.0080)  # above the trim's voltage


def test_the_shaft_rate_answers_the_pump_at_once(model, trim):
    """Fuel reaches the turbine's torque within milliseconds, so the shaft is first order: its
    rate per pump volt levels off at K / tau (steady gain over the time constant) above the
    shaft's pole instead of rolling off as the document's second-order fast model's does (at
    50 rad/s the model's is 0.1 %N/s per V). The MRAC's rate gain K_x2 meets
    this flat gain (docs/ecu.md, command smoothness)."""
    steady, lin = trim
    w = np.array([8.0, 20.0, 50.0])
    got = speed_rate_per_volt(model, steady, TRIM_FUEL, w)
    first_order = lin.gain_pct_per_v / lin.tau_s
    assert got == pytest.approx(first_order * np.ones(3), rel=0.2)
    assert got[-1] > 10.0 * rate_per_volt(50.0)
