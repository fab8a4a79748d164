"""The engine from standstill: starter, light-off, pooled fuel, hot section, start faults.

Expectations come from physics (the shaft's energy balance, the hot section's heat balance, the
fuel's mass balance), from the light-off rules of plant.ignition, and from determinism.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant import hot_section as hs
from plant.aerothermal import AeroThermalPlant
from plant.faults import Fault, FaultKind
from plant.interface import PlantConfig
from plant.starter import motor_current, starter_torque


def _spin(plant: AeroThermalPlant, seconds: float, duty: float, igniter: bool = False) -> list:
    """Run the starter alone (pump off) and return the outputs' (n %, supply V) per period."""
    rows = []
    for _ in range(round(seconds / plant.config.ecu_period_s)):
        o = plant.step(0.0, True, duty, igniter)
        rows.append((o.n_pct, o.supply_v, o.egt_true_k, o.burning))
    return rows


def _start(plant: AeroThermalPlant, pump_v: float, igniter_from_s: float = 1.0) -> dict:
    """An open-loop start: starter at 0.5 duty, igniter on from igniter_from_s, the pump at
    pump_v from 3 s. Returns the light-off time, peak T4 and EGT and the unburnt fuel."""
    lit_at = None
    peak_t4 = peak_egt = 0.0
    for k in range(1500):
        t = k * 0.01
        o = plant.outputs
        duty = pump_v / max(o.supply_v, 1.0) if t >= 3.0 else 0.0
        plant.step(duty, True, 0.5, t >= igniter_from_s and lit_at is None)
        if lit_at is None and plant.outputs.burning:
            lit_at = t
        peak_t4 = max(peak_t4, plant.outputs.t4_k)
        peak_egt = max(peak_egt, plant.outputs.egt_true_k)
    return {
        "lit_at": lit_at,
        "peak_t4": peak_t4,
        "peak_egt": peak_egt,
        "unburnt_kg": plant.outputs.unburnt_fuel_kg,
    }


def test_standstill_starts_at_rest_cold_and_unlit():
    p = AeroThermalPlant(PlantConfig(standstill=True))
    o = p.outputs
    assert o.n_pct == 0.0 and o.burning == 0.0 and o.fuel_kg_s == 0.0
    assert o.hot_section_k == pytest.approx(p.config.ambient.t0_k, abs=0.5)
    assert p.trim_duty == 0.0
    o = p.step(0.0)  # nothing commanded: nothing moves
    assert o.n_pct == 0.0 and o.starter_current_a == 0.0


def test_motor_line_and_overrunning_clutch():
    k, r = 0.004, 0.3
    assert motor_current(24.0, 0.0, k, r) == pytest.approx(80.0)  # stall
    assert motor_current(24.0, 24.0 / k, k, r) == 0.0  # no load
    assert motor_current(12.0, 24.0 / k, k, r) == 0.0  # the clutch frees: no braking
    assert starter_torque(24.0, 0.0, k, r, 0.5) == pytest.approx(0.5 * k * 80.0)


def test_shaft_energy_balance_during_a_starter_spin_up():
    """1/2 J (w1^2 - w0^2) = integral of (eta_m P_t - P_c + starter torque x w) dt."""
    plant = AeroThermalPlant(PlantConfig(standstill=True))
    params = plant.model.params
    j, eta_m = params.inertia_kg_m2, params.eta_m
    w_per_pct = 0.01 * params.n_max_rpm * math.pi / 30.0
    duty, dt = 0.6, plant.config.ecu_period_s
    ws, net = [0.0], [0.0]
    for _ in range(400):
        plant.step(0.0, True, duty)
        w = plant.outputs.n_pct * w_per_pct
        supply = plant.outputs.supply_v
        torque = starter_torque(duty * supply, w, params.starter_emf_v_s, params.starter_r_ohm, 1.0)
        ws.append(w)
        st = plant.stations
        net.append(eta_m * st.power_turbine - st.power_compressor + torque * w)
    kinetic = 0.5 * j * (ws[-1] ** 2 - ws[0] ** 2)
    work = np.trapezoid(net, dx=dt)
    assert ws[-1] > 5.0 * w_per_pct  # it spun up
    assert work == pytest.approx(kinetic, rel=0.02)


def test_hot_section_gives_the_gas_what_the_metal_loses():
    g, cp, c = 0.05, 1100.0, hs.HEAT_CAPACITY_J_K
    eps = hs.effectiveness(g, cp, hs.CONDUCTANCE_W_K)
    assert eps == pytest.approx(1.0 - math.exp(-hs.CONDUCTANCE_W_K / (g * cp)))
    t6 = hs.gas_out(400.0, 800.0, eps)
    assert 400.0 < t6 < 800.0
    assert c * hs.metal_rate(g, cp, 400.0, t6, c) == pytest.approx(-g * cp * (t6 - 400.0))
    assert hs.gas_out(400.0, hs.IN_EQUILIBRIUM, eps) == 400.0
    assert hs.effectiveness(0.0, cp, hs.CONDUCTANCE_W_K) == 1.0


def test_no_light_without_the_igniter_and_the_fuel_pools_unburnt():
    plant = AeroThermalPlant(PlantConfig(standstill=True))
    r = _start(plant, 2.0, igniter_from_s=99.0)
    assert r["lit_at"] is None
    delivered = r["unburnt_kg"]
    assert delivered > 1e-3  # the pump delivered fuel, all of it unburnt
    assert plant.outputs.egt_true_k < 300.0


def test_fuel_mass_balance_without_a_flame():
    """Unburnt fuel = the integral of the pump's delivery while nothing burns."""
    plant = AeroThermalPlant(PlantConfig(standstill=True))
    _spin(plant, 3.0, 0.5)
    integral = 0.0
    last = plant.outputs.fuel_kg_s
    for _ in range(500):
        o = plant.step(2.1 / max(plant.outputs.supply_v, 1.0), True, 0.5)
        integral += 0.5 * (last + o.fuel_kg_s) * 0.01
        last = o.fuel_kg_s
    assert integral > 1e-3
    assert plant.outputs.unburnt_fuel_kg == pytest.approx(integral, rel=0.02)


def test_light_off_with_the_igniter_inside_the_fuel_air_window():
    plant = AeroThermalPlant(PlantConfig(standstill=True))
    r = _start(plant, 2.0)
    assert r["lit_at"] is not None and 3.0 < r["lit_at"] < 8.0
    assert plant.outputs.egt_true_k > 400.0  # burning: the exhaust heats


def test_too_rich_does_not_light():
    plant = AeroThermalPlant(PlantConfig(standstill=True))
    r = _start(plant, 6.0)  # about 4 g/s into 5 g/s of air: far over FAR_RICH
    assert r["lit_at"] is None


def test_igniter_failure_means_no_light_off():
    fault = Fault(0.0, FaultKind.IGNITER_FAILURE)
    plant = AeroThermalPlant(PlantConfig(standstill=True, faults=(fault,)))
    assert _start(plant, 2.0)["lit_at"] is None


def test_a_late_light_off_on_a_pool_is_a_hot_start():
    prompt = _start(AeroThermalPlant(PlantConfig(standstill=True)), 2.0)
    late = _start(AeroThermalPlant(PlantConfig(standstill=True)), 2.0, igniter_from_s=9.0)
    assert late["lit_at"] is not None and late["lit_at"] > 9.0
    assert late["unburnt_kg"] > 2.0 * prompt["unburnt_kg"]
    assert late["peak_egt"] > prompt["peak_egt"] + 150.0  # the pool burns on after light-off


def test_starter_failure_leaves_the_rotor_at_rest():
    fault = Fault(0.0, FaultKind.STARTER_FAILURE, 0.0)
    plant = AeroThermalPlant(PlantConfig(standstill=True, faults=(fault,)))
    rows = _spin(plant, 2.0, 1.0)
    assert rows[-1][0] == 0.0
    assert plant.outputs.starter_current_a == 0.0


def test_fuel_starvation_blows_the_flame_out():
    plant = AeroThermalPlant(PlantConfig(initial_speed_pct=60.0))
    assert plant.outputs.burning == 1.0
    plant.inject(Fault(0.05, FaultKind.FUEL_STARVATION, 1e-4))
    for _ in range(200):
        o = plant.step(plant.trim_duty)
    assert o.burning == 0.0
    assert o.fuel_kg_s <= 1e-4 + 1e-12


def test_cool_down_with_the_starter():
    """After a run, fuel cut: the starter blows the hot section below 373 K within 60 s."""
    plant = AeroThermalPlant(PlantConfig(initial_speed_pct=60.0, hot_section=True))
    metal0 = plant.outputs.hot_section_k
    assert metal0 > 600.0
    egt = []
    for k in range(6000):
        o = plant.step(0.0, False, 1.0 if k > 300 else 0.0)
        egt.append(o.egt_true_k)
    assert o.burning == 0.0
    assert egt[-1] < 373.0
    assert o.hot_section_k < metal0
    assert np.all(np.diff(egt[400:]) <= 1e-6)  # cooling, never heating, once blowing


def test_a_start_is_deterministic():
    a = _start(AeroThermalPlant(PlantConfig(standstill=True, seed=3)), 2.0)
    b = _start(AeroThermalPlant(PlantConfig(standstill=True, seed=3)), 2.0)
    assert a == b


def test_a_start_in_steady_state_keeps_the_documents_hot_section():
    """Without the thermal mass (the default from steady state) the EGT is the turbine's exit
    gas at every instant, as in the document; with it, the EGT lags the gas in a transient."""
    runs = {}
    for mass in (False, True):
        plant = AeroThermalPlant(PlantConfig(initial_speed_pct=80.0, hot_section=mass))
        duty = plant.trim_duty
        egt = [plant.step(duty * (1.15 if k > 20 else 1.0)).egt_true_k for k in range(300)]
        runs[mass] = egt
        assert PlantConfig(initial_speed_pct=80.0).hot_section_mass is False
    assert runs[False][0] == pytest.approx(runs[True][0])  # the same steady state
    assert np.max(np.abs(np.subtract(runs[False], runs[True]))) > 5.0  # the metal lags the gas
