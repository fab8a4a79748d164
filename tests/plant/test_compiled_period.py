"""The compiled period gives the bits of the Python it replaced: pump driver, sensors, the fast
plant's running-line lookup (numpy.interp), the node's frames (the codec's); a copied plant goes
on as the original."""

from __future__ import annotations

import copy
import math
import struct
from dataclasses import astuple

import numpy as np
import pytest

from plant import flags as fl
from plant.aerothermal import AeroThermalPlant, default_maps
from plant.fast_plant import FastPlant, _interp_at, _locate
from plant.faults import Fault, FaultKind
from plant.frames import frame_layout
from plant.interface import PlantConfig
from plant.periphery import (
    BATTERY_R,
    BATTERY_V,
    IDLE_A,
    OUT,
    OUT_FIELDS,
    PER_PA,
    PER_VOLT,
    PUMP_STATE,
    SPEED,
    THERMO,
    pump_driver,
)
from plant.pump import PumpState, supply_and_pump_voltage
from plant.sensors import (
    SP_BIAS,
    SP_DROPOUT,
    SP_DROPOUT_P,
    SP_LAST,
    SP_RESOLUTION,
    SP_SIGMA,
    SP_STUCK,
    TC_ALPHA,
    TC_BIAS,
    TC_LAG,
    TC_NOISE,
    TC_OPEN,
    TC_OPEN_K,
    TC_PROBE,
    speed_reading,
    thermocouple_reading,
)
from protocol.codec import Codec


def bits(values) -> list[str]:
    return [struct.pack("<d", float(v)).hex() for v in values]


def test_pump_driver_is_the_python_driver_bit_for_bit():
    table = default_maps().pump
    rng = np.random.default_rng(0)
    s = np.zeros(64)
    s[IDLE_A], s[PER_VOLT], s[PER_PA] = (
        table.current_idle_a,
        table.current_per_volt,
        table.current_per_pa,
    )
    for _ in range(3000):
        duty = float(rng.choice([0.0, -0.0, 1.0, rng.random()]))
        battery, r = float(rng.uniform(0.0, 30.0)), float(rng.choice([0.0, rng.uniform(0, 2)]))
        p = float(rng.choice([0.0, -0.0, rng.uniform(-2e5, 8e5)]))
        state = PumpState(int(rng.integers(3)))
        s[BATTERY_V], s[BATTERY_R], s[PUMP_STATE] = battery, r, state
        expected = supply_and_pump_voltage(duty, battery, r, p, table, state)
        assert bits(pump_driver(s, duty, p)) == bits(expected)


def _python_speed(n_rpm, z, u, sigma, resolution, bias, p_drop, dropout, stuck, last):
    """SpeedPickup.read as it was in Python."""
    value = max(n_rpm + bias + sigma * z, 0.0)
    if resolution > 0.0:
        value = round(value / resolution) * resolution
    if dropout or u < p_drop:
        value = 0.0
    if stuck:
        value = last
    return value


def test_speed_reading_is_the_python_reading_bit_for_bit():
    rng = np.random.default_rng(1)
    s = np.zeros(64)
    b = SPEED
    for _ in range(5000):
        n = float(rng.choice([0.0, 5.0, 15.0, rng.uniform(0, 120_000)]))
        z, u = float(rng.standard_normal()), float(rng.random())
        sigma = float(rng.choice([0.0, 20.0, math.hypot(20.0, 300.0)]))
        resolution = float(rng.choice([0.0, 10.0, 25.0, 0.3]))
        bias = float(rng.choice([0.0, -30.0, 12.5]))
        p_drop = float(rng.choice([0.0, 0.1]))
        dropout, stuck = bool(rng.random() < 0.1), bool(rng.random() < 0.1)
        last = s[b + SP_LAST]
        expected = _python_speed(n, z, u, sigma, resolution, bias, p_drop, dropout, stuck, last)
        s[b + SP_SIGMA], s[b + SP_RESOLUTION], s[b + SP_BIAS] = sigma, resolution, bias
        s[b + SP_DROPOUT_P], s[b + SP_DROPOUT], s[b + SP_STUCK] = p_drop, dropout, stuck
        got = speed_reading(s, b, n, z, u)
        assert bits([got]) == bits([expected]) and s[b + SP_LAST] == got


def test_thermocouple_reading_is_the_python_reading_bit_for_bit():
    rng = np.random.default_rng(2)
    s = np.zeros(64)
    b = THERMO
    probe = 900.0
    s[b + TC_PROBE] = probe
    for _ in range(3000):
        egt, z = float(rng.uniform(300, 1400)), float(rng.standard_normal())
        tau = float(rng.choice([0.0, 0.5, 1.3]))
        noise, bias, open_ = float(rng.choice([0.0, 1.0])), float(rng.choice([0.0, 2.5])), False
        open_ = bool(rng.random() < 0.1)
        alpha = 1.0 - math.exp(-0.01 / tau) if tau > 0.0 else 0.0
        if tau > 0.0:  # Thermocouple.read as it was in Python
            probe += (egt - probe) * (1.0 - math.exp(-0.01 / tau))
        else:
            probe = egt
        expected = 1638.3 if open_ else probe + bias + noise * z
        s[b + TC_LAG], s[b + TC_ALPHA], s[b + TC_BIAS], s[b + TC_NOISE] = (
            tau > 0.0,
            alpha,
            bias,
            noise,
        )
        s[b + TC_OPEN_K], s[b + TC_OPEN] = 1638.3, open_
        got = thermocouple_reading(s, b, egt, z)
        assert bits([got, s[b + TC_PROBE]]) == bits([expected, probe])


def test_running_line_lookup_is_numpy_interp_bit_for_bit():
    line = FastPlant()._table
    xp = line["N_pct"]
    rng = np.random.default_rng(3)
    points = np.concatenate(
        [xp, xp + 1e-9, xp - 1e-9, rng.uniform(xp[0] - 5, xp[-1] + 5, 3000), [-1.0, 200.0]]
    )
    for column in ("P3_Pa", "P5_Pa", "T4_K", "EGT_K", "air_kg_s", "thrust_N"):
        fp = line[column]
        for x in points.tolist():
            got = _interp_at(x, _locate(xp, x), xp, fp)
            assert bits([got]) == bits([np.interp(x, xp, fp)]), (column, x)


@pytest.mark.parametrize("cls", [AeroThermalPlant, FastPlant])
def test_a_copied_plant_goes_on_as_the_original(cls):
    faults = (Fault(0.1, FaultKind.SPEED_NOISE_BURST, 200.0, 0.1),)
    plant = cls(PlantConfig(seed=3, faults=faults))
    for _ in range(5):
        plant.step(plant.trim_duty)
    twin = copy.deepcopy(plant)
    for _ in range(40):
        a = astuple(plant.step(0.6))
        b = astuple(twin.step(0.6))
        assert a == b
    assert plant.speed_pickup.burst_noise_rpm == twin.speed_pickup.burst_noise_rpm == 0.0


def test_compiled_frames_are_the_codec_frames_also_when_saturated():
    from plant.frames import FRAMES, pack_plant_frames

    codec, packed = Codec(), Codec()
    messages = [codec[name] for name in FRAMES]
    lay = frame_layout([packed[name] for name in FRAMES])
    buf = np.zeros(8 * len(FRAMES), dtype=np.uint8)
    s = np.zeros(OUT + len(OUT_FIELDS))
    rng = np.random.default_rng(4)
    for k in range(400):
        values = rng.choice([0.0, -5.0, 0.5, 2.5, 1e7, 1e12], size=len(OUT_FIELDS))
        values = np.where(rng.random(len(OUT_FIELDS)) < 0.5, values, rng.uniform(0, 2e5))
        s[OUT:] = values
        o = dict(zip(OUT_FIELDS, values.tolist(), strict=True))
        flags, tick16 = int(rng.integers(1 << 10)), k % 70_000 % 65536
        pack_plant_frames(s, lay, buf, flags, tick16, 3)
        clamped = fl.COMPRESSOR_MAP_CLAMPED | fl.TURBINE_MAP_CLAMPED | fl.PUMP_MAP_CLAMPED
        raws = (
            [
                1 if flags & fl.FLAMEOUT else 0,
                1 if flags & clamped else 0,
                1 if flags & fl.OVERSPEED else 0,
                1 if flags & fl.OVERTEMPERATURE else 0,
                round(o["p3_pa"] * 0.1),
                round(o["p5_pa"] * 0.1),
                round(o["t4_k"] * 10.0),
            ],
            [round(o["fuel_kg_s"] * 1e6), round(o["thrust_n"] * 20.0), round(o["n_rpm"])],
            [
                1 if o["burning"] != 0.0 else 0,
                round(o["hot_section_k"] * 10.0),
                round(o["starter_current_a"] * 20.0),
                round(o["unburnt_fuel_kg"] * 1e6),
            ],
            [tick16, round(o["supply_v"] * 1000.0), round(o["pump_current_a"] * 1000.0)],
            [tick16, round(o["speed_rpm"]), round(o["egt_k"] * 10.0)],
        )
        for i, (m, raw) in enumerate(zip(messages, raws, strict=True)):
            m.pack_raw(raw)
            assert bytes(buf[8 * i : 8 * i + 8]) == bytes(m.data), (m.name, raw)
