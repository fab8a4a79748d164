"""The C core through ctypes against the Python firmware, tick by tick and field by field, on
random inputs over the whole DBC ranges (not only what a plant produces); errors name the field."""

import ctypes
import random
from array import array

import pytest

from ecu.firmware import Ecu, EcuInputs
from ecu.firmware_params import compile_params
from ecu.params import RATE_BUF_LEN, EcuParams
from ecu.port import build, core
from ecu.state import EcuState

# raw input ranges of the CAN contract (DBC) and E2E statuses
RANGES = {
    "speed_rpm": (0, 150000),
    "egt_dk": (0, 16383),
    "supply_mv": (0, 65535),
    "pump_ma": (0, 65535),
    "demand_cpct": (0, 12000),
    "open_loop_mv": (0, 30000),
}


def _state_difference(py: EcuState, c) -> str | None:
    for name in EcuState.FIELDS:
        a, b = getattr(py, name), getattr(c, name)
        if isinstance(a, array):
            a, b = list(a), list(b)
        if a != b:
            return f"{name}: python {a}, c {b}"
    return None


def _fuzz(params: EcuParams, ticks: int, seed: int, wild: float) -> None:
    """Mostly plausible inputs around trim, with a fraction `wild` drawn anywhere in range."""
    rng = random.Random(seed)
    py, c = Ecu(params), core.CEcu(params)
    i = EcuInputs()
    n = 100900.0
    for k in range(ticks):
        n += rng.gauss(0.0, 300.0) + (100900.0 - n) * 0.02
        i.tick = k % 65536
        i.speed_rpm = round(n)
        i.egt_dk = 10480 + rng.randint(-300, 2500)
        i.supply_mv = 22200 + rng.randint(-4000, 1000)
        i.pump_ma = 1700 + rng.randint(-1700, 4000)
        i.demand_cpct = rng.choice((8968, 9500, 8000, 3500, 10500))
        i.open_loop_mv = 11560 + rng.randint(-3000, 3000)
        for name, (lo, hi) in RANGES.items():
            if rng.random() < wild:
                setattr(i, name, rng.randint(lo, hi))
        i.arm = 0 if rng.random() < 0.002 else 1
        i.stop = 1 if rng.random() < 0.001 else 0
        for status in ("sensor_status", "analog_status", "demand_status"):
            setattr(i, status, 0 if rng.random() < 0.9 else rng.randint(1, 4))
        if k % 700 == 0:  # re-initialise now and then (FAULT latches)
            py.reset()
            c.reset()
        a, b = py.tick(i), c.tick(i)
        for name in a.FIELDS:
            assert getattr(a, name) == getattr(b, name), f"tick {k}: output {name}"
        assert (diff := _state_difference(py.s, c.s)) is None, f"tick {k}: state {diff}"


@pytest.mark.parametrize("controller", ["mrac", "pid", "open_loop"])
def test_c_core_equals_python_on_random_inputs(controller):
    _fuzz(EcuParams(controller=controller), 3000, seed=len(controller), wild=0.05)


@pytest.mark.parametrize("rate_hz", [50, 1000])
def test_c_core_equals_python_at_other_tick_rates(rate_hz):
    _fuzz(EcuParams(rate_hz=rate_hz, rate_window_s=0.05), 3000, seed=rate_hz, wild=0.05)


def test_c_core_equals_python_with_robustness_off_and_wild_inputs():
    params = EcuParams(
        lambda_floor_on=False, dead_zone_on=False, freeze_on=False, limiters_on=False
    )
    _fuzz(params, 3000, seed=99, wild=0.5)


def test_digest_matches_the_python_digest():
    from ecu.golden import state_digest

    py, c = Ecu(), core.CEcu()
    i = EcuInputs()
    i.speed_rpm, i.egt_dk, i.supply_mv, i.demand_cpct, i.arm = 100900, 10480, 22200, 9000, 1
    for _ in range(50):
        py.tick(i)
        c.tick(i)
    assert c.digest() == state_digest(py.s)


def test_a_field_missing_on_one_side_is_named():
    lib = core.library().lib
    k = EcuState.FIELDS.index("hist_idx")
    expected = EcuState.FIELDS[:k] + ("hist_cursor",) + EcuState.FIELDS[k + 1 :]
    with pytest.raises(core.PortError, match="'hist_idx' \\(C\\) vs 'hist_cursor' \\(Python\\)"):
        core._record(lib, "ecu_state_names", expected, "ecu_state_t")


def test_parameters_the_c_core_cannot_run_are_refused_by_name():
    p = compile_params(EcuParams())
    p.rate_half_window = 40  # the window would not fit the speed history ring
    with pytest.raises(core.PortError, match="FirmwareParams.rate_half_window"):
        core.CEcu(p)
    p = compile_params(EcuParams())
    p.v_max_q24 = 1 << 40
    with pytest.raises(core.PortError, match="FirmwareParams.v_max_q24 = 1099511627776"):
        core.CEcu(p)


def test_unknown_implementation_and_missing_compiler_are_explained(monkeypatch):
    with pytest.raises(ValueError, match="'rust': expected one of python, c"):
        core.make_ecu("rust")
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.raises(build.PortBuildError, match="no C compiler found"):
        build.host_compiler()


def test_ecu_t_layout_matches_the_c_size():
    """The wrapper's ecu_t is the C struct: ecu_tick writes outputs where Python reads them."""
    lib = core.library()
    c = core.CEcu()
    out_offset = type(c._ecu).o.offset
    returned = lib.lib.ecu_tick(ctypes.byref(c._ecu), ctypes.byref(c._in))
    assert returned == ctypes.addressof(c._ecu) + out_offset


_STRUCTURAL = {  # state words that index or enumerate: kept in their valid ranges
    "hist_idx": (0, RATE_BUF_LEN - 1),
    "hist_fill": (0, RATE_BUF_LEN),
    "speed_seen": (0, RATE_BUF_LEN),
    "mode": (0, 4),
    "owner": (0, 4),
    "v_saturated": (0, 1),
    "arm": (0, 1),
    "stop": (0, 1),
    "speed_failed": (0, 1),
    "faults": (0, 0xFFFF),
    "speed_rpm": (0, 262143),
    "egt_dk": (0, 16383),
    "supply_mv": (0, 65535),
    "pump_ma": (0, 65535),
    "sat_events": (0, 1 << 30),
    "ticks": (0, 1 << 30),
    "sensor_age": (0, 300),
    "analog_age": (0, 300),
    "demand_age": (0, 300),
}


def _extreme(rng: random.Random) -> int:
    roll = rng.random()
    if roll < 0.3:
        return rng.randint(-(1 << 31), (1 << 31) - 1)
    if roll < 0.5:
        return rng.choice((-(1 << 31), (1 << 31) - 1, 0, -1, 1))
    return rng.randint(-(1 << 26), 1 << 26)


def _randomise_state(rng: random.Random, py: EcuState, c) -> None:
    for name in EcuState.FIELDS:
        value = getattr(py, name)
        if isinstance(value, array):
            for k in range(len(value)):
                if name == "theta_ext":
                    value[k] = rng.randint(0, 65535)
                elif name == "n_hist_rpm":
                    value[k] = rng.randint(0, 262143)
                else:
                    value[k] = _extreme(rng)
                getattr(c, name)[k] = value[k]
        else:
            if name in _STRUCTURAL:
                value = rng.randint(*_STRUCTURAL[name])
            elif name.endswith("_cnt"):
                value = rng.randint(0, 3)
            else:
                value = _extreme(rng)
            setattr(py, name, value)
            setattr(c, name, value)


@pytest.mark.parametrize("controller", ["mrac", "pid", "open_loop"])
def test_one_tick_from_extreme_states_is_equal(controller):
    """From random states with Q values anywhere in int32 (saturation and 64-bit overflow paths:
    products of two unsaturated intermediates need more than 64 bits), one tick: same result."""
    rng = random.Random(controller)
    params = EcuParams(controller=controller)
    py, c = Ecu(params), core.CEcu(params)
    i = EcuInputs()
    for trial in range(1000):
        _randomise_state(rng, py.s, c.s)
        i.tick = trial
        for name, (lo, hi) in RANGES.items():
            setattr(i, name, rng.randint(lo, hi))
        i.arm, i.stop = rng.randint(0, 1), int(rng.random() < 0.1)
        for status in ("sensor_status", "analog_status", "demand_status"):
            setattr(i, status, rng.choice((0, 0, 0, 1, 4)))
        a, b = py.tick(i), c.tick(i)
        for name in a.FIELDS:
            assert getattr(a, name) == getattr(b, name), f"trial {trial}: output {name}"
        assert (diff := _state_difference(py.s, c.s)) is None, f"trial {trial}: state {diff}"


def test_assigning_parameters_applies_them_from_the_next_tick():
    """As the service port does on a parameter write: ``ecu.p = new`` on both firmwares."""
    py, c, unchanged = Ecu(), core.CEcu(), Ecu()
    i = EcuInputs()
    i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma, i.arm = 100900, 10480, 22200, 1700, 1
    faster = compile_params(EcuParams(ref_wn=8.0, gamma_lambda=3.0, v_slew_v_s=50.0))
    differs = 0
    for k in range(600):
        if k == 300:
            py.p = c.p = faster
        i.demand_cpct = 9300 if (k // 100) % 2 else 8700
        i.speed_rpm += (py.out.pump_mv - 11560) // 40
        a, b = py.tick(i), c.tick(i)
        for name in a.FIELDS:
            assert getattr(a, name) == getattr(b, name), f"tick {k}: output {name}"
        differs += unchanged.tick(i).nref_cpct != a.nref_cpct
    assert differs > 100  # the new set did change the control
    assert c.p is faster
    refused = compile_params(EcuParams())
    refused.rate_half_window = 0
    with pytest.raises(core.PortError, match="rate_half_window"):
        c.p = refused
    assert c.p is faster and c._params.rate_half_window == faster.rate_half_window
