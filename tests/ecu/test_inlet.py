"""The day's inlet temperature (ecu.inlet): read from the EGT at rest before a start, it sets the
schedules' corrected speed and the start's EGT target; the operator's inlet_temp_k otherwise."""

from __future__ import annotations

import math
from dataclasses import replace

from hypothesis import given
from hypothesis import strategies as st

from ecu import modes as M
from ecu.firmware import E2E_OK, Ecu, EcuInputs
from ecu.firmware_params import compile_params
from ecu.inlet import INLET_MAX_DK, INLET_MIN_DK, T_STD_CK, day_target_dk, ncor_k_q24
from ecu.params import EcuParams
from ecu.port.build import PORT_DIR

Q = 1 << 24


@given(st.integers(INLET_MIN_DK * 10, INLET_MAX_DK * 10))
def test_corrected_speed_factor_is_the_floor_of_the_exact_root(inlet_ck: int) -> None:
    k = ncor_k_q24(inlet_ck)
    exact = math.sqrt(T_STD_CK / inlet_ck) * Q
    assert k <= exact < k + 1.0001  # the floor (float rounding at the last bit aside)


def test_the_start_target_is_the_same_corrected_temperature_under_the_cap() -> None:
    p = EcuParams()  # 1180 K at 288.15 K, HOT_START at 1250 K, 20 K margin
    target, cap = round(p.start_egt_target_k * 10), round((1250.0 - 20.0) * 10)
    assert day_target_dk(target, cap, T_STD_CK) == target  # the standard day: the parameter
    assert day_target_dk(target, cap, 25300) == 11800 * 25300 // 28815  # 1036.0 K on 253 K
    assert day_target_dk(target, cap, 31700) == cap  # 1298 K on 317 K: capped at 1230 K
    fw = compile_params(p)
    assert fw.seq_day_target_dk == target and fw.ncor_k_q24 == Q  # the operator's 288.15 K


def _arm_at(egt_k: float, params: EcuParams) -> Ecu:
    """An ECU armed at rest with its thermocouple reading egt_k."""
    ecu, i = Ecu(params), EcuInputs()
    i.egt_dk, i.supply_mv, i.demand_cpct = round(egt_k * 10), 22200, 5500
    i.sensor_status = i.analog_status = i.demand_status = E2E_OK
    for k in range(3):
        i.tick, i.arm = k, 1 if k else 0
        ecu.tick(i)
    assert ecu.out.mode == M.ARMED
    return ecu


def test_a_start_from_rest_takes_the_day_from_the_egt() -> None:
    p = EcuParams(inlet_temp_k=288.15)
    hot = _arm_at(317.0, p)
    assert hot.s.ncor_k_q24 == ncor_k_q24(31700)
    assert abs(hot.s.ncor_k_q24 / Q - math.sqrt(288.15 / 317.0)) < 1e-6
    assert hot.s.seq_target_dk == 12300  # 1180 K x 317 / 288.15 = 1298 K, capped
    cold = _arm_at(253.0, p)
    assert cold.s.seq_target_dk == 10360 and cold.s.ncor_k_q24 > Q
    fw = compile_params(p)
    for ecu in (
        _arm_at(360.0, p),  # warm from a run: not the air's temperature
        _arm_at(317.0, replace(p, inlet_from_egt=False)),  # the operator's day only
    ):
        assert (ecu.s.ncor_k_q24, ecu.s.seq_target_dk) == (fw.ncor_k_q24, fw.seq_day_target_dk)


def test_the_c_port_accepts_the_same_range() -> None:
    text = (PORT_DIR / "generated" / "ecu_constants.h").read_text()  # ecu.port.constants
    assert f"#define ECU_INLET_MIN_DK {INLET_MIN_DK} " in text
    assert f"#define ECU_INLET_MAX_DK {INLET_MAX_DK} " in text
    assert f"#define ECU_T_STD_CK {T_STD_CK} " in text
