"""Scenario files: shipped ones load, bad ones are refused naming file and field."""

import json
import subprocess
import sys

import numpy as np
import pytest

from ecu.params import preset
from sil import scenario
from sil.scenario import profiles

REQUIRED = [
    "thesis-3.3-staircase",
    "thesis-3.3-square",
    "thesis-3.3-sine",
    "thesis-3.1-band-90-94",
    "thesis-4.2-estimator-fast",
    "thesis-4.3-estimator-aero",
    "thesis-5.2-mrac-fast",
    "thesis-5.3-mrac-aero",
    "thesis-5.4-staircase",
    "thesis-5.4-sine",
    "thesis-5.4-staircase-sine",
    "thesis-6.1-pid",
    "thesis-6.2-staircase-pid",
    "thesis-6.3-failure-mrac",
    "thesis-6.3-failure-pid",
]


def test_the_documents_cases_are_shipped():
    assert set(REQUIRED) <= set(scenario.shipped_names())
    for name in REQUIRED:
        s = scenario.load(name)
        assert s.name == name and s.duration_s > 0 and s.description


def test_document_settings():
    assert scenario.load("thesis-5.3-mrac-aero").duration_s == 300
    failure = scenario.load("thesis-6.3-failure-mrac")
    assert failure.faults == (scenario.Fault(30.0, "PUMP_EFFECTIVENESS", 0.5),)
    assert scenario.load("thesis-6.3-failure-pid").controller.kind == "pid"
    assert scenario.load("thesis-5.2-mrac-fast").plant.model == "fast"


MINIMAL = "duration_s = 10\n[command]\nbase = 90\n"


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("duration_s = -1\n[command]\n", "field 'duration_s': expected a positive number, got -1"),
        ("[command]\n", "field 'duration_s' is missing"),
        (MINIMAL + "[plant]\nmodel = 'jet'\n", "field 'plant.model': expected one of aero, fast"),
        (
            MINIMAL + "[[command.component]]\nkind = 'square'\namplitude = 1\nfrequency_hz = 0\n",
            "field 'command.component[0].frequency_hz': expected a positive number",
        ),
        (
            MINIMAL + "[[command.component]]\nkind = 'saw'\n",
            "field 'command.component[0].kind': expected one of",
        ),
        (MINIMAL + "[[fault]]\ntime_s = 5\ntarget = 'GREMLINS'\n", "field 'fault[0].target'"),
        (
            MINIMAL + "[[fault]]\ntime_s = 50\ntarget = 'PUMP_EFFECTIVENESS'\n",
            "field 'fault[0].time_s': expected a time within the run",
        ),
        ("ecu_rate_hz = 5000\n" + MINIMAL, "field 'ecu_rate_hz': expected a number in 50..1000"),
        ("colour = 'red'\n" + MINIMAL, "unknown field 'colour'"),
        (MINIMAL + "colour = 'red'\n", "unknown field 'command.colour'"),
        ("duration_s = 10\n[command]\nbase = 'idle'\n", "field 'command.base'"),
        ("duration_s = = 1", "not valid TOML"),
        (MINIMAL + "[controller]\npreset = 'sec9'\n", "field 'controller.preset': expected one of"),
        (
            "duration_s = 10\n[controller.params]\nwarp = 9\n[command]\n",
            "field 'controller.params.warp': expected an ECU parameter",
        ),
        (
            "duration_s = 10\n[controller.params]\ninit_kx = [-4.8]\n[command]\n",
            "field 'controller.params.init_kx': expected a list of 2 numbers",
        ),
        (
            "duration_s = 10\n[controller.params]\ninit_kx = [-4.8, nan]\n[command]\n",
            "field 'controller.params.init_kx': expected a list of 2 finite numbers",
        ),
        (
            "duration_s = 10\n[controller.params]\nref_wn = [5]\n[command]\n",
            "field 'controller.params.ref_wn': expected a number",
        ),
        (
            MINIMAL + "[[command.component]]\nkind = 'staircase'\nlevels = []\nstep_s = 1\n",
            "field 'command.component[0].levels': expected a non-empty list",
        ),
        (
            "duration_s = 10\n[plant]\ninitial_speed_pct = 5\n[command]\n",
            "field 'plant.initial_speed_pct': expected a number in 10..120",
        ),
        (
            "duration_s = 10\n[plant]\ninitial_egt_max_K = 'hot'\n[command]\n",
            "field 'plant.initial_egt_max_K': expected a number",
        ),
    ],
)
def test_bad_files_name_the_file_and_field(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(scenario.ScenarioError) as exc:
        scenario.load(path)
    assert str(path) in str(exc.value)
    assert words in str(exc.value)


def test_csv_component_and_its_errors(tmp_path):
    (tmp_path / "cmd.csv").write_text("time_s,value\n0,80\n10,90\n")
    path = tmp_path / "s.toml"
    path.write_text(MINIMAL + "[[command.component]]\nkind = 'csv'\npath = 'cmd.csv'\n")
    s = scenario.load(path)
    values = profiles.sample(s.profile(89.68), 10, 1)
    assert values[0] == 170 and values[5] == 175 and values[10] == 180
    (tmp_path / "cmd.csv").write_text("time_s,value\n0,80\n1,abc\n")
    with pytest.raises(scenario.ScenarioError, match="line 3"):
        scenario.load(path)


def test_unknown_name_lists_shipped():
    with pytest.raises(scenario.ScenarioError, match="thesis-5.3-mrac-aero"):
        scenario.load("no-such-scenario")


def test_profiles_sum_and_shapes():
    t = np.array([0.0, 5.0, 10.0, 15.0, 25.0])
    assert list(profiles.Square(1.0, 0.05)(t)) == [1, 1, -1, -1, 1]
    assert list(profiles.Staircase((1.0, 2.0), 10.0, start_s=5.0)(t)) == [0, 1, 1, 2, 2]
    assert list(profiles.Step(10.0, 3.0)(t)) == [0, 0, 3, 3, 3]
    assert profiles.Sine(2.0, 0.05)(np.array([5.0]))[0] == pytest.approx(2.0)
    assert list(profiles.Ramp(0.0, 10.0, 4.0)(t)) == [0, 2, 4, 4, 4]
    total = profiles.Profile(89.68, (profiles.Square(1.0, 0.05), profiles.Step(10.0, 1.0)))
    assert list(total(t)) == pytest.approx([90.68, 90.68, 89.68, 89.68, 91.68])
    assert len(profiles.sample(total, 300, 100)) == 30_001


def test_scenarios_command_lists_and_checks(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "sil.cli", "scenarios", "--json"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert {r["name"] for r in json.loads(out)} >= set(REQUIRED)
    bad = tmp_path / "bad.toml"
    bad.write_text("duration_s = 'long'\n")
    result = subprocess.run(
        [sys.executable, "-m", "sil.cli", "scenarios", "--check", str(bad)],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2 and "duration_s" in result.stderr


def test_a_start_speed_is_the_plants_not_the_ecus(tmp_path):
    """The plant starts where the scenario says; the ECU keeps the commissioned trim."""
    from sil.run.config import build_plant, ecu_trim_voltage

    path = tmp_path / "start.toml"
    path.write_text("duration_s = 10\n[plant]\ninitial_speed_pct = 75\n[command]\n")
    s = scenario.load(path)
    assert s.plant.initial_speed_pct == 75.0 and not s.plant.varied
    plant = build_plant(s, 0)
    assert plant.outputs.n_pct == pytest.approx(75.0, abs=0.05)
    nominal = build_plant(scenario.load(scenario.SCENARIO_DIR / "thesis-5.4-staircase.toml"), 0)
    assert ecu_trim_voltage(s, plant) == nominal.trim_pump_voltage != plant.trim_pump_voltage


def test_table_and_pair_parameters_are_lists_of_numbers(tmp_path):
    path = tmp_path / "s.toml"
    line = [round(5.0 + k, 2) for k in range(12)]
    path.write_text(
        "duration_s = 10\n[controller.params]\n"
        f"accel_line_v = {line}\ninit_kx = [-1, -0.5]\nv_slew_v_s = 20\n[command]\n"
    )
    params = preset("default", **scenario.load(path).controller.params)  # validated
    assert params.accel_line_v == tuple(float(v) for v in line) and params.init_kx == (-1.0, -0.5)
    assert params.v_slew_v_s == 20.0


def _with_fault(target: str, value: float | None, model: str = "aero") -> str:
    fault = f"[[fault]]\ntime_s = 1\ntarget = '{target}'\n"
    fault += "" if value is None else f"value = {value!r}\n"
    return f"duration_s = 10\n[plant]\nmodel = '{model}'\n[command]\n{fault}"


@pytest.mark.parametrize("target", scenario.fault_targets())
def test_fault_values_are_checked_against_the_plant_and_the_frame(tmp_path, target):
    from plant.faults import target_value_range

    frame_lo, frame_hi = scenario.fault_value_field()
    code = scenario.fault_targets().index(target)  # the DBC's FaultTarget values are 0..15
    plant_lo, plant_hi = target_value_range(code) or (frame_lo, frame_hi)
    lo, hi = max(plant_lo, frame_lo), min(plant_hi, frame_hi)  # SPEED_NOISE: the frame's
    path = tmp_path / "f.toml"
    for edge in (lo, hi):
        path.write_text(_with_fault(target, edge))
        assert scenario.load(path).faults[0].value == edge
    for outside in (lo - max(1.0, abs(lo)), hi + max(1.0, abs(hi)), 1e39):
        path.write_text(_with_fault(target, outside))
        with pytest.raises(scenario.ScenarioError, match=rf"field 'fault\[0\].value'.*{target}"):
            scenario.load(path)


def test_a_fault_the_fast_plant_lacks_is_refused(tmp_path):
    path = tmp_path / "f.toml"
    path.write_text(_with_fault("TURBINE_FLOW", 0.9, model="fast"))
    with pytest.raises(scenario.ScenarioError, match=r"field 'fault\[0\].target'.*fast plant"):
        scenario.load(path)
    path.write_text(_with_fault("PUMP_EFFECTIVENESS", 0.5, model="fast"))
    assert scenario.load(path).faults[0].target == "PUMP_EFFECTIVENESS"


def test_run_and_check_refuse_a_fault_value_the_plant_would_drop(tmp_path):
    path, out = tmp_path / "f.toml", tmp_path / "o"
    path.write_text(_with_fault("PUMP_EFFECTIVENESS", 5))
    for args in (("scenarios", "--check", str(path)), ("run", str(path), "--out", str(out))):
        result = subprocess.run(
            [sys.executable, "-m", "sil.cli", *args], capture_output=True, text=True
        )
        assert result.returncode == 2, result.stderr
        assert f"{path}: field 'fault[0].value': expected a number in 0..1" in result.stderr
    assert not out.exists()
