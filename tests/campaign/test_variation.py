"""Engine variation as built; bus faults in `sil run --mode inproc`: repeatable."""

from dataclasses import replace

import pytest

from plant.aerothermal import AeroThermalPlant
from plant.interface import PlantConfig
from sil import scenario as scenarios
from sil.run.config import build_plant, ecu_trim_voltage
from sil.run.runner import RunOptions, run
from sil.scenario import PlantSettings


def test_health_scalars_are_in_the_initial_steady_state_and_pump_gain_scales_fuel():
    nominal = AeroThermalPlant(PlantConfig())
    weak = AeroThermalPlant(PlantConfig(compressor_efficiency=0.95))
    # same fuel flow, a less efficient compressor: a slower, hotter engine, at rest from tick 0
    assert weak.outputs.n_pct < nominal.outputs.n_pct - 2.0
    assert weak.outputs.egt_true_k > nominal.outputs.egt_true_k + 20.0
    n0 = weak.outputs.n_pct
    assert weak.step(weak.trim_duty).n_pct == pytest.approx(n0, abs=0.01)
    strong = AeroThermalPlant(PlantConfig(pump_gain=1.2))
    # 20 % more fuel per volt: the trim point needs less voltage, same engine
    assert strong.trim_pump_voltage < nominal.trim_pump_voltage - 1.0
    assert strong.outputs.n_pct == pytest.approx(nominal.outputs.n_pct)


def test_the_ecu_keeps_the_nominal_engines_trim_voltage():
    s = scenarios.load("thesis-5.4-staircase")
    varied = replace(s, plant=replace(s.plant, pump_gain=1.2, turbine_flow=0.96))
    assert varied.plant.varied and not s.plant.varied
    plant = build_plant(varied, 1)
    assert plant.trim_pump_voltage != pytest.approx(build_plant(s, 1).trim_pump_voltage)
    assert ecu_trim_voltage(varied, plant) == build_plant(s, 1).trim_pump_voltage


def test_fast_plant_refuses_health_scalars(tmp_path):
    text = 'duration_s = 1\n[plant]\nmodel = "fast"\ncompressor_flow = 0.9\n[command]\n'
    with pytest.raises(scenarios.ScenarioError, match="'plant.compressor_flow'"):
        scenarios.parse(text, "x.toml", tmp_path)
    assert PlantSettings().varied is False


BUS_FAULTED = """
duration_s = 2
seed = 5
[plant]
pump_gain = 1.1
[controller]
preset = "default"
[command]
base = 85
[[bus_fault]]
kind = "drop"
ids = ["PlantSensors", "Demand"]
start_s = 0.5
rate = 0.3
duration_s = 1
[[bus_fault]]
kind = "delay"
ids = ["EcuActuator"]
start_s = 1
duration_s = 0.5
delay_ticks = 1
jitter_ticks = 2
"""


def test_inproc_run_with_bus_faults_repeats_byte_for_byte(tmp_path):
    path = tmp_path / "faulted.toml"
    path.write_text(BUS_FAULTED)
    s = scenarios.load(path)
    a = run(RunOptions(s, tmp_path / "a", mode="inproc", plots=False, progress=False))
    b = run(RunOptions(s, tmp_path / "b", mode="inproc", plots=False, progress=False))
    assert a["status"] == "completed" and a["bus_faults_injected"] == b["bus_faults_injected"]
    kinds = {e["kind"] for e in a["bus_faults_injected"]}
    assert kinds == {"drop", "delay"}
    assert (tmp_path / "a" / "can.log").read_bytes() == (tmp_path / "b" / "can.log").read_bytes()
