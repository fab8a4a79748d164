"""Trim at 8 g/s against the published state (eq. 2.32) and the balances that define it."""

from __future__ import annotations

import json

import pytest

from plant.engine import EngineParams
from plant.thermo import cp_air
from sil.cli import main


def test_parameters_are_the_documents(reference):
    ref = reference["aero_thermal_parameters"]
    p = EngineParams(nozzle_area_m2=1.0)
    assert (p.t0_k, p.p0_pa, p.u0_m_s) == (
        ref["ambient_T0_K"],
        ref["ambient_P0_Pa"],
        ref["flight_speed_U0_m_s"],
    )
    assert (p.v_pc_m3, p.v_jp_m3) == (
        ref["compressor_plenum_volume_m3"],
        ref["jet_pipe_plenum_volume_m3"],
    )
    assert p.inertia_kg_m2 == ref["rotor_inertia_kg_m2"]
    assert (p.cp_fuel, p.lhv) == (ref["fuel_cp_J_kgK"], ref["fuel_LHV_J_kg"])
    assert (p.eta_loss, p.tau_b, p.eta_b) == (
        ref["burner_pressure_loss_ratio"],
        ref["burner_time_constant_s"],
        ref["burner_efficiency"],
    )
    assert (p.eta_n, p.eta_m) == (ref["nozzle_efficiency"], ref["mechanical_efficiency"])
    assert p.n_max_rpm == reference["engine_spec_amt_olympus"]["max_speed_rpm"]


def test_trim_reaches_the_published_state(trim, reference):
    ref = reference["trim_point_eq_2_32"]
    p3, p5, t4, n = trim.x
    assert p3 == pytest.approx(ref["P3_Pa"], rel=0.02)
    assert p5 == pytest.approx(ref["P5_Pa"], rel=0.02)
    assert t4 == pytest.approx(ref["T4_K"], rel=0.02)
    assert n == pytest.approx(ref["N_pct"], abs=0.5)
    assert trim.residual < 1e-9


def test_mass_is_conserved_through_the_components(trim):
    st = trim.stations
    assert st.g3 == pytest.approx(st.g2, rel=1e-9)  # compressor plenum, eq. 2.12
    assert st.g4 == pytest.approx(st.g3 + st.g_fuel, rel=1e-12)  # burner, eq. 2.16
    assert st.g6 == pytest.approx(st.g4, rel=1e-9)  # jet-pipe plenum, eq. 2.22


def test_shaft_power_and_burner_energy_balance(trim, model):
    st, p = trim.stations, model.params
    assert p.eta_m * st.power_turbine == pytest.approx(st.power_compressor, rel=1e-9)  # 2.31
    t4 = trim.x[2]
    energy_in = st.g3 * cp_air(st.t3) * st.t3 + st.g_fuel * (p.cp_fuel * p.t0_k + p.eta_b * p.lhv)
    assert energy_in == pytest.approx(st.g4 * cp_air(t4) * t4, rel=1e-9)  # 2.15 at rest


def test_trim_matches_the_briefs_energy_balance(trim):
    """BRIEF: an energy balance at the trim puts air near 0.33 kg/s, EGT near 1030 K, thrust
    near 175 N; our Cp(T) polynomial gives somewhat less air and thrust."""
    st = trim.stations
    assert 0.27 < st.g2 < 0.35
    assert st.t5 == pytest.approx(1030.0, abs=40.0)
    assert 140.0 < st.thrust < 190.0


def test_sil_trim_json(capsys, reference):
    assert main(["trim", "--fuel", "0.008", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {
        "P3_Pa",
        "P5_Pa",
        "T4_K",
        "N_pct",
        "N_rpm",
        "EGT_K",
        "thrust_N",
        "air_kg_s",
        "fuel_kg_s",
    }
    assert out["N_rpm"] == pytest.approx(out["N_pct"] * 1125.0)
    assert out["P3_Pa"] == pytest.approx(reference["trim_point_eq_2_32"]["P3_Pa"], rel=0.02)


@pytest.mark.parametrize("fuel", ["-0.001", "nan", "inf", "0"])
def test_sil_trim_refuses_bad_fuel(fuel, capsys):
    assert main(["trim", "--fuel", fuel]) == 2
    assert "fuel flow" in capsys.readouterr().err


def test_sil_trim_below_the_lean_limit_says_so(capsys):
    assert main(["trim", "--fuel", "0.0005"]) == 2
    err = capsys.readouterr().err
    assert "0.50 g/s" in err
    assert "flames out" in err or "no running engine" in err


def test_ram_compression_raises_delivery_pressure(capsys):
    assert main(["trim", "--json", "--flight-speed", "150"]) == 0
    ram = json.loads(capsys.readouterr().out)
    assert main(["trim", "--json"]) == 0
    static = json.loads(capsys.readouterr().out)
    assert ram["P3_Pa"] > static["P3_Pa"] * 1.05


# -- starting at a speed (each engine of a variation where its governor holds it) -------------


def _varied(model, ce, cf, te, tf):
    return model._replace(
        params=model.params._replace(
            comp_eff_scale=ce, comp_flow_scale=cf, turb_eff_scale=te, turb_flow_scale=tf
        )
    )


def _rates_scaled(model, g, x):
    import numpy as np

    from plant.engine import engine_rates
    from plant.trim import SCALE

    dxdt = np.empty(4)
    engine_rates(x, g, 1.0, model, dxdt)
    return np.abs(dxdt / SCALE)


@pytest.mark.parametrize("n_pct", [60.0, 75.0, 89.68, 97.0])
def test_steady_state_at_a_speed_holds_it(model, n_pct):
    from plant.trim import solve_steady_at_speed

    g, s = solve_steady_at_speed(model, n_pct)
    assert s.x[3] == pytest.approx(n_pct, abs=1e-6)
    assert max(_rates_scaled(model, g, s.x)) < 1e-6  # a steady state: every rate zero
    assert s.stations.g2 == pytest.approx(s.stations.g6 - g, rel=1e-6)  # air in = gas out - fuel


def test_steady_state_at_the_trim_speed_is_the_trim(model, trim):
    from plant.trim import solve_steady_at_speed

    g, s = solve_steady_at_speed(model, float(trim.x[3]))
    assert g == pytest.approx(0.008, rel=1e-6)


def test_a_hot_engine_starts_at_its_egt_limit_below_the_speed(model):
    from plant.trim import solve_steady, solve_steady_at_speed

    weak = _varied(model, 0.95, 0.95, 0.95, 0.95)  # 80 %N and 1218 K at 8 g/s
    assert solve_steady(weak, 0.008).stations.t5 > 1200.0
    g, s = solve_steady_at_speed(weak, 90.0, egt_max_k=1250.0)
    assert s.stations.t5 == pytest.approx(1250.0, abs=0.01)
    assert s.x[3] < 90.0
    assert max(_rates_scaled(weak, g, s.x)) < 1e-6
    g_free, free = solve_steady_at_speed(weak, 90.0)  # without the limit: the speed, hotter
    assert free.x[3] == pytest.approx(90.0, abs=1e-6) and free.stations.t5 > 1250.0


def test_an_engine_hot_everywhere_starts_at_its_coolest_point(model):
    from plant.trim import solve_steady_at_speed

    weak = _varied(model, 0.95, 1.05, 0.95, 0.95)  # EGT never falls under about 1283 K
    g, s = solve_steady_at_speed(weak, 90.0, egt_max_k=1200.0)
    step = 0.0005
    for other in (g - step, g + step):  # its neighbours on the line are hotter
        from plant.trim import solve_steady

        assert solve_steady(weak, other, x0=s.x).stations.t5 >= s.stations.t5 - 0.5


def test_plant_started_at_a_speed_stays_there():
    from plant.aerothermal import AeroThermalPlant
    from plant.interface import PlantConfig

    plant = AeroThermalPlant(PlantConfig(initial_speed_pct=75.0, pump_gain=1.2))
    for _ in range(200):  # 2 s at its own trim voltage
        out = plant.step(plant.trim_duty)
    assert out.n_pct == pytest.approx(75.0, abs=0.02)


def test_plant_refuses_a_bad_start():
    from plant.interface import PlantConfig

    with pytest.raises(ValueError, match="initial_speed_pct"):
        PlantConfig(initial_speed_pct=5.0)
    with pytest.raises(ValueError, match="initial_egt_max_k"):
        PlantConfig(initial_speed_pct=90.0, initial_egt_max_k=-1.0)


def test_an_engine_that_runs_no_slower_starts_at_its_slowest_steady_state(model):
    from plant.trim import FUEL_STEP_KG_S, solve_steady, solve_steady_at_speed

    weak = _varied(model, 0.95, 0.95, 0.95, 0.95)  # no steady state down at 40 %N
    g, s = solve_steady_at_speed(weak, 40.0)
    assert 40.0 < s.x[3] < 60.0
    assert max(_rates_scaled(weak, g, s.x)) < 1e-6
    with pytest.raises((ValueError, RuntimeError)):  # a step less fuel keeps it running no more
        solve_steady(weak, g - FUEL_STEP_KG_S, x0=s.x, settle_s=5.0)
