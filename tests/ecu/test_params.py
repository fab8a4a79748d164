"""Parameter structure: presets, refusal of unsafe values (naming the field), discretisation."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ecu.firmware_params import _tustin, compile_params
from ecu.params import PRESETS, EcuParams, ParamError, preset, validate

REF = Path(__file__).resolve().parents[3] / "shared" / "reference" / "thesis_reference.json"


def test_every_preset_compiles() -> None:
    for name in PRESETS:
        fw = compile_params(PRESETS[name])
        assert fw.rate_hz == 100


def test_presets_carry_the_documents_values() -> None:
    ref = json.loads(REF.read_text())
    s42 = ref["online_estimation_on_fast_model_sec_4_2"]
    p = preset("sec4_2_estimator")
    assert list(p.am_row2) == s42["Am"][1]
    assert list(p.init_ap_row2) == s42["initial"]["Ap_row2"]
    assert p.init_lambda == s42["initial"]["Lambda"]
    assert list(p.gamma_a) == s42["gains"]["Gamma_A"]
    assert p.gamma_lambda == s42["gains"]["Gamma_Lambda"]
    assert list(p.gamma_theta) == s42["gains"]["Gamma_Theta"]
    assert p.p22 == s42["P"][1][1]
    for key, name in (
        ("indirect_mrac_on_fast_model_sec_5_2", "sec5_2_mrac_fast"),
        ("indirect_mrac_on_aero_thermal_sec_5_3", "sec5_3_mrac_aero"),
    ):
        g = ref[key]["gains"]
        p = preset(name)
        assert list(p.gamma_a) == g["Gamma_A"] and p.gamma_lambda == g["Gamma_Lambda"]
        assert list(p.gamma_theta) == g["Gamma_Theta"]
        assert list(p.gamma_x) == g["Gamma_x"] and p.gamma_r == g["Gamma_r"]
        assert list(p.gamma_f) == g["Gamma_f"]
    rm = ref["indirect_mrac_on_fast_model_sec_5_2"]["reference_model"]
    p = preset("sec5_2_mrac_fast")
    assert -(p.ref_wn**2) == rm["Am"][1][0] and -2 * p.ref_zeta * p.ref_wn == rm["Am"][1][1]
    assert list(p.am_row2) == rm["Am"][1]


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("rate_hz", 40),
        ("rate_hz", 2000),
        ("controller", "bang-bang"),
        ("am_row2", (0.5, -1.0)),
        ("p22", 0.0),
        ("gamma_lambda", -1.0),
        ("gamma_theta", (1000.0, 1.0)),
        ("init_lambda", 0.0),
        ("v_max", 0.1),
        ("n_limit_pct", 106.0),
        ("egt_limit_k", 1400.0),
        ("duty_max", 1.5),
        ("trim_v", float("nan")),
        ("demand_hold_s", 3.0),
    ],
)
def test_unsafe_parameters_are_refused_by_name(field: str, value: object) -> None:
    with pytest.raises(ParamError, match=field):
        compile_params(replace(EcuParams(), **{field: value}))


def test_unknown_preset_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown ECU preset"):
        preset("nope")


@pytest.mark.parametrize("rate_hz", [50, 100, 1000])
def test_tustin_matches_the_matrix_formula(rate_hz: int) -> None:
    a = np.array([[0.0, 1.0], [-25.0, -10.0]])
    dt = 1.0 / rate_hz
    inv = np.linalg.inv(np.eye(2) - dt / 2 * a)
    m, h = _tustin(a[1, 0], a[1, 1], dt)
    assert np.allclose(np.array(m).reshape(2, 2), inv @ (np.eye(2) + dt / 2 * a), atol=1e-14)
    assert np.allclose(h, (inv * dt)[:, 1], atol=1e-14)


@pytest.mark.parametrize("value", [1e300, 2, -1, 0.5])
def test_a_switch_is_on_or_off_and_nothing_else(value):
    with pytest.raises(ParamError, match=r"fuel_schedules_on=.*: a switch is true or false"):
        validate(replace(EcuParams(), fuel_schedules_on=value))


def test_a_commissioning_the_ecu_refuses_is_refused_naming_the_file(tmp_path):
    from ecu import commissioning

    path = tmp_path / "engine.json"
    path.write_text(
        '{"format": "turbojet-sil commissioning 1", "trim_N_pct": -5, "trim_V": -12,'
        ' "Ap_row2": [-1.8, -2.3], "Lambda": 4.8, "Theta_row2": [-0.18, 0.0]}'
    )
    with pytest.raises(ParamError, match=rf"{path}: the ECU refuses .*trim_n_pct=-5"):
        commissioning.commission(EcuParams(), path)
