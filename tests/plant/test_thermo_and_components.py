"""Component functions against independent textbook formulas and tables."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant import flags as fl
from plant.compressor import compressor
from plant.intake import intake
from plant.lookup import check_axis, interp1, interp2
from plant.nozzle import PR_LINEAR, nozzle
from plant.thermo import R_AIR, cp_air, gamma_air

# ideal-gas dry air, Cengel & Boles table A-17 (h differences) / A-2b, J/(kg K)
CP_TABLE = [
    (300.0, 1005.0),
    (400.0, 1013.0),
    (500.0, 1029.0),
    (800.0, 1099.0),
    (1000.0, 1141.0),
    (1200.0, 1175.0),
]


@pytest.mark.parametrize(("t_k", "cp_ref"), CP_TABLE)
def test_cp_polynomial_matches_air_tables(t_k, cp_ref):
    assert cp_air(t_k) == pytest.approx(cp_ref, rel=0.005)


def test_gamma_of_cold_and_hot_air():
    assert gamma_air(300.0) == pytest.approx(1.400, abs=0.002)
    assert gamma_air(1100.0) == pytest.approx(1.33, abs=0.01)


def test_cp_is_held_outside_its_fitted_band():
    assert cp_air(5000.0) == cp_air(1600.0)
    assert cp_air(10.0) == cp_air(200.0)


def test_intake_ram_recovery_is_isentropic():
    p2, t2 = intake(101325.0, 288.15, 150.0)
    g = gamma_air(0.5 * (288.15 + t2))
    m0 = 150.0 / math.sqrt(gamma_air(288.15) * R_AIR * 288.15)
    assert t2 == pytest.approx(288.15 * (1 + 0.5 * (g - 1) * m0 * m0), rel=1e-6)
    assert p2 == pytest.approx(101325.0 * (t2 / 288.15) ** (g / (g - 1)), rel=1e-6)
    assert intake(101325.0, 288.15, 0.0) == (101325.0, 288.15)


def _ideal_nozzle_flow(p6, t6, p0, area):
    """Textbook isentropic convergent nozzle, eta_n = 1, gamma at T6."""
    g = gamma_air(t6)
    crit = (2 / (g + 1)) ** (g / (g - 1))
    r = max(p0 / p6, crit)
    return (
        area
        * p6
        / math.sqrt(t6)
        * math.sqrt(2 * g / (R_AIR * (g - 1)) * (r ** (2 / g) - r ** ((g + 1) / g)))
    )


@pytest.mark.parametrize("pr", [1.2, 1.6, 1.8, 2.5, 3.0])
def test_nozzle_flow_matches_isentropic_theory(pr):
    g7, _, _ = nozzle(pr * 101325.0, 1000.0, 101325.0, 0.0, 1.5e-3, 1.0)
    assert g7 == pytest.approx(
        _ideal_nozzle_flow(pr * 101325.0, 1000.0, 101325.0, 1.5e-3), rel=1e-9
    )


def test_nozzle_chokes_at_the_critical_ratio():
    g = gamma_air(1000.0)
    pr_crit = ((g + 1) / 2) ** (g / (g - 1))
    _, _, below = nozzle(0.99 * pr_crit * 101325.0, 1000.0, 101325.0, 0.0, 1.5e-3, 0.98)
    g_a, f_a, above = nozzle(1.2 * pr_crit * 101325.0, 1000.0, 101325.0, 0.0, 1.5e-3, 0.98)
    g_b, _, _ = nozzle(1.44 * pr_crit * 101325.0, 1000.0, 101325.0, 0.0, 1.5e-3, 0.98)
    assert not below and above
    assert g_b / g_a == pytest.approx(1.2, rel=1e-9)  # choked: flow proportional to P6
    assert f_a > g_a * 0.0  # thrust includes the pressure term and is positive


def test_nozzle_low_pressure_law_is_continuous_and_defined_in_reverse():
    p_lin = PR_LINEAR * 101325.0
    hi = nozzle(p_lin * (1 + 1e-9), 900.0, 101325.0, 0.0, 1.5e-3, 0.98)[0]
    lo = nozzle(p_lin * (1 - 1e-9), 900.0, 101325.0, 0.0, 1.5e-3, 0.98)[0]
    assert lo == pytest.approx(hi, rel=1e-6)
    assert nozzle(101325.0, 900.0, 101325.0, 0.0, 1.5e-3, 0.98)[0] == 0.0
    assert nozzle(100000.0, 900.0, 101325.0, 0.0, 1.5e-3, 0.98)[0] < 0.0


def test_compressor_temperature_rise_and_power(model):
    c = model.compressor
    g2, t3, power, flags = compressor(101325.0, 288.15, 2.5 * 101325.0, 80.0, c, 1.0, 1.0)
    eta, _ = interp2(c.flow_axis, c.n_cor_pct, c.efficiency, g2, 80.0)
    g = gamma_air(0.5 * (288.15 + t3))
    t3_ref = 288.15 * (1 + (2.5 ** ((g - 1) / g) - 1) / eta)
    assert t3 == pytest.approx(t3_ref, rel=1e-3)  # one fixed-point pass on gamma
    assert power == pytest.approx(g2 * (cp_air(t3) * t3 - cp_air(288.15) * 288.15), rel=1e-12)
    assert flags == 0


def test_compressor_off_its_map_clamps_and_flags(model):
    _, _, _, flags = compressor(101325.0, 288.15, 20 * 101325.0, 90.0, model.compressor, 1.0, 1.0)
    assert flags & fl.COMPRESSOR_MAP_CLAMPED
    assert flags & fl.SURGE


def test_lookup_is_exact_at_nodes_linear_between_and_clamps():
    x = np.array([0.0, 1.0, 2.0])
    y = np.array([10.0, 20.0])
    t = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]])
    assert interp2(x, y, t, 1.0, 20.0) == (3.0, False)
    assert interp2(x, y, t, 0.5, 15.0)[0] == pytest.approx(1.5)
    assert interp2(x, y, t, 3.0, 25.0) == (5.0, True)
    assert interp1(x, np.array([0.0, 2.0, 4.0]), -1.0) == (0.0, True)
    with pytest.raises(ValueError, match="evenly spaced"):
        check_axis("x", np.array([0.0, 1.0, 3.0]))
