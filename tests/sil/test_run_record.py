"""A run folder holds what shaped its run (scenario.toml as run, commissioning.json, run.json),
so that `sil replay LOG --into-ecu` sets the ECU up as the run did: 0 differing frames; a log
that differs is named at its first differing tick and signal, with exit 1."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from protocol.codec import Codec
from sil import scenario as scenarios
from sil.run.run_record import Overrides, scenario_text

DOCTORED_TICK = 150


@pytest.mark.parametrize("name", scenarios.shipped_names())
def test_the_scenario_as_run_is_its_file_or_its_fields_with_the_runs_changes(tmp_path, name):
    s = scenarios.load(name)
    assert scenario_text(s, s.seed) == s.path.read_text()  # nothing changed: the file itself
    changed = Overrides(controller="pid", preset="default", params={"gamma_r": 0.3}).apply(s)
    changed = replace(changed, duration_s=s.duration_s / 2, stop_s=None)
    path = tmp_path / "scenario.toml"
    path.write_text(scenario_text(changed, seed=s.seed + 7))
    again = scenarios.load(path)
    assert again.seed == s.seed + 7 and again.duration_s == s.duration_s / 2
    assert again.stop_s is None and again.name == s.name
    assert again.controller == replace(
        s.controller, kind="pid", preset="default", params={**s.controller.params, "gamma_r": 0.3}
    )
    assert (again.plant, again.faults, again.bus_faults) == (s.plant, s.faults, s.bus_faults)
    assert (again.command_base, again.command_components) == (s.command_base, s.command_components)


@pytest.fixture(scope="module")
def commissioned_run(tmp_path_factory, sil, udp_spec) -> Path:
    """A lockstep run over the loopback bus with a commissioning file from `sil identify` (on an
    open-loop staircase run), a seed of its own and a parameter changed on the command line."""
    tmp = tmp_path_factory.mktemp("record")
    stair = tmp / "staircase"
    ran = sil("run", "thesis-3.3-staircase", "--mode", "inproc", "--out", str(stair), "--no-plots")
    assert ran.returncode == 0, ran.stderr
    engine = tmp / "engine.json"
    ident = sil("identify", str(stair / "trace.csv"), "--export", str(engine))
    assert ident.returncode == 0, ident.stderr
    scenario = tmp / "short.toml"
    scenario.write_text(
        (scenarios.SCENARIO_DIR / "thesis-5.4-staircase.toml")
        .read_text()
        .replace("duration_s = 130", "duration_s = 4")
    )
    out = tmp / "run"
    ran = sil(
        "run", str(scenario), "--bus", udp_spec(), "--out", str(out), "--no-plots",
        "--commission", str(engine), "--seed", "7", "--param", "gamma_r=0.3",
    )  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    engine.unlink()  # the run folder's copy is what counts from here on
    return out


@pytest.mark.slow
def test_a_run_folder_records_what_shaped_the_run(commissioned_run):
    record = json.loads((commissioned_run / "run.json").read_text())
    assert record["seed"] == 7 and record["mode"] == "lockstep" and record["ecu_impl"] == "python"
    assert record["overrides"] == {"params": {"gamma_r": 0.3}}
    assert record["commissioning_file"] == "commissioning.json"
    assert record["command_line"][:2] == ["sil", "run"] and "--seed" in record["command_line"]
    commissioning = json.loads((commissioned_run / "commissioning.json").read_text())
    assert commissioning["format"] == "turbojet-sil commissioning 1"
    ran = scenarios.load(commissioned_run / "scenario.toml")
    assert ran.seed == 7 and ran.controller.params["gamma_r"] == 0.3
    summary = json.loads((commissioned_run / "summary.json").read_text())
    assert summary["run"]["overrides"] == record["overrides"] and summary["seed"] == 7


@pytest.mark.slow
def test_a_recorded_run_replays_into_the_ecu_with_no_difference(commissioned_run, sil):
    same = sil("replay", str(commissioned_run / "can.log"), "--into-ecu", "--json")
    assert same.returncode == 0, same.stderr
    report = json.loads(same.stdout)
    assert report["ticks"] == 401 and report["frames_compared"] > 800
    assert report["frames_differing"] == report["frames_missing"] == report["frames_extra"] == 0
    assert report["commissioning"] == str(commissioned_run / "commissioning.json")
    # the scenario as its file says, without the run's gamma_r: another ECU
    other = sil(
        "replay", str(commissioned_run / "can.log"), "--into-ecu", "--scenario",
        str(scenarios.SCENARIO_DIR / "thesis-5.4-staircase.toml"),
    )  # fmt: skip
    assert other.returncode == 1 and "differs from the recording from tick " in other.stderr
    assert "EcuTelemetry Gain_Kr: recorded " in other.stderr


@pytest.mark.slow
def test_a_doctored_log_is_named_at_its_first_differing_tick_and_signal(
    commissioned_run, sil, tmp_path
):
    folder = tmp_path / "doctored"
    shutil.copytree(commissioned_run, folder)
    db = Codec().database
    lines = (folder / "can.log").read_text().splitlines(keepends=True)
    actuators = [i for i, line in enumerate(lines) if " 110#" in line]
    i = actuators[DOCTORED_TICK]
    head, payload = lines[i].rstrip("\n").split("#")
    values = db.decode_message(0x110, bytes.fromhex(payload), decode_choices=False)
    assert values["ActuatorTick"] == DOCTORED_TICK
    values["PumpVoltageTarget"] += 0.5
    lines[i] = f"{head}#{db.encode_message(0x110, values).hex().upper()}\n"
    (folder / "can.log").write_text("".join(lines))
    result = sil("replay", str(folder / "can.log"), "--into-ecu", "--out", str(tmp_path / "cmp"))
    assert result.returncode == 1
    assert (
        f"the ECU emulator differs from the recording from tick {DOCTORED_TICK} "
        f"(t = {DOCTORED_TICK / 100:.3f} s): EcuActuator PumpVoltageTarget: recorded "
    ) in result.stderr, result.stderr
    assert "(1 of " in result.stderr and " frames differing, 0 missing, 0 extra)" in result.stderr
    report = json.loads((tmp_path / "cmp" / "report.json").read_text())
    first = report["first_difference"]
    assert first["tick"] == DOCTORED_TICK and first["message"] == "EcuActuator"
    recorded, replayed = first["signals"]["PumpVoltageTarget"]
    assert recorded - replayed == pytest.approx(0.5, abs=0.01)


@pytest.mark.slow
def test_a_run_repeats_from_its_own_folder(commissioned_run, sil, tmp_path, first_difference):
    """The folder's scenario.toml and commissioning.json give the run again (in process: the
    lockstep run's can.log byte for byte), even into that same folder."""
    folder = tmp_path / "again"
    shutil.copytree(commissioned_run, folder)
    log = (folder / "can.log").read_bytes()
    ran = sil(
        "run", str(folder / "scenario.toml"), "--commission", str(folder / "commissioning.json"),
        "--mode", "inproc", "--out", str(folder), "--no-plots",
    )  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert first_difference((folder / "can.log").read_bytes(), log) is None


@pytest.mark.slow
def test_a_real_time_run_is_not_replayed_tick_for_tick(commissioned_run, sil, tmp_path):
    folder = tmp_path / "rt"
    shutil.copytree(commissioned_run, folder)
    record = json.loads((folder / "run.json").read_text())
    (folder / "run.json").write_text(json.dumps({**record, "mode": "realtime"}))
    result = sil("replay", str(folder / "can.log"), "--into-ecu")
    assert result.returncode == 2 and "a real-time run (run.json)" in result.stderr
