"""Property: damaged scenario files and option values give exit 0, 1 or 2 and no traceback.

Covered: damaged scenario, campaign and log files, run folders, bus specs, option values
(`--speed`, `--workers`, `trim`, node options), fault values, and the trim point of an
identification export (only a file the ECU loads is written). The number of examples is
``SIL_ROBUSTNESS_EXAMPLES`` (default 200; the slow properties run a fraction of it) for a longer
run.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sil import cli
from sil.scenario import fault_targets

EXAMPLES = int(os.environ.get("SIL_ROBUSTNESS_EXAMPLES", "200"))
SETTINGS = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)

VALID = """name = "t"
duration_s = 1
ecu_rate_hz = 100
seed = 1
[plant]
model = "aero"
[controller]
kind = "mrac"
[command]
base = "trim"
[[command.component]]
kind = "step"
time_s = 0.5
value = 1.0
"""

odd_numbers = st.sampled_from(["nan", "inf", "-inf", "-1", "0", "1e308", '"x"', "true", "[]"])
lines = VALID.splitlines()


def _damage(data: st.DataObject) -> str:
    kind = data.draw(st.sampled_from(["value", "drop", "unknown", "truncate", "garbage"]))
    out = list(lines)
    numeric = [i for i, line in enumerate(out) if "=" in line and not line.startswith("[")]
    i = data.draw(st.sampled_from(numeric))
    if kind == "value":
        out[i] = f"{out[i].split('=')[0].strip()} = {data.draw(odd_numbers)}"
    elif kind == "drop":
        del out[i]
    elif kind == "unknown":
        out.insert(i + 1, "bogus_field = 1")
    elif kind == "truncate":
        text = "\n".join(out)
        return text[: data.draw(st.integers(0, len(text)))]
    else:
        return data.draw(st.binary(max_size=200)).decode("latin-1")
    return "\n".join(out) + "\n"


def _main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse's usage errors
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def test_the_valid_scenario_passes_the_check(tmp_path: Path, capsys) -> None:
    path = tmp_path / "s.toml"
    path.write_text(VALID)
    assert _main(["scenarios", "--check", str(path)], capsys)[0] == 0


@SETTINGS
@given(data=st.data())
def test_damaged_scenarios_are_refused_in_one_line(tmp_path: Path, capsys, data) -> None:
    path = tmp_path / "s.toml"
    path.write_text(_damage(data), encoding="latin-1")
    code, output = _main(["scenarios", "--check", str(path)], capsys)
    assert code in (0, 2)
    assert "Traceback" not in output
    if code == 2:
        assert len(output.strip().splitlines()) == 1
        assert str(path) in output


@SETTINGS
@given(speed=st.floats(allow_nan=True, allow_infinity=True))
def test_replay_speed_must_be_within_its_range(tmp_path: Path, capsys, speed: float) -> None:
    log = tmp_path / "can.log"
    log.write_text("(0.000000) vcan0 100#00\n")
    code, output = _main(["replay", str(log), "--dry-run", f"--speed={speed}"], capsys)
    assert "Traceback" not in output
    if not math.isfinite(speed) or not 0.001 <= speed <= 1000:
        assert code == 2
    else:
        assert code in (0, 1)


@pytest.mark.parametrize("fuel", ["0.1", "1", "-1", "nan", "inf", "0"])
def test_trim_refuses_fuel_outside_the_envelope(capsys, fuel: str) -> None:
    code, output = _main(["trim", f"--fuel={fuel}"], capsys)
    assert code == 2
    assert "Traceback" not in output
    assert len(output.strip().splitlines()) == 1


def test_trim_answers_at_the_documents_trim(capsys) -> None:
    assert _main(["trim", "--fuel=0.008"], capsys)[0] == 0


@pytest.mark.parametrize("param", ["foo=1", "idle_pct=nan", "idle_pct", "=3"])
def test_ecu_refuses_a_bad_param_in_one_line(capsys, param: str) -> None:
    code, output = _main(["ecu", "--bus", "virtual:robustness", "--ticks", "1", "--param", param],
                         capsys)  # fmt: skip
    assert code == 2
    assert output.strip().startswith("sil ecu: --param")


def _trace(path: Path, speed: list[float], volts: list[float]) -> Path:
    rows = [f"{0.01 * i},{n},{v}" for i, (n, v) in enumerate(zip(speed, volts, strict=True))]
    path.write_text("time,speed_meas,PumpVoltageTarget\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize(
    ("speed", "volts", "why"),
    [
        ([90.0] * 200, [10.0 + (i // 50) for i in range(200)], "speed (the output) is constant"),
        ([90.0 + i % 7 for i in range(200)], [10.0] * 200, "voltage (the input) is constant"),
        ([90.0, float("nan")] * 100, [10.0 + (i // 50) for i in range(200)], "NaN"),
        ([90.0 + i for i in range(5)], [10.0 + i for i in range(5)], "only 5 usable samples"),
    ],
)
def test_identify_refuses_data_that_identifies_nothing(
    tmp_path: Path, capsys, speed: list[float], volts: list[float], why: str
) -> None:
    export = tmp_path / "commission.json"
    trace = _trace(tmp_path / "trace.csv", speed, volts)
    code, output = _main(["identify", str(trace), "--export", str(export)], capsys)
    assert code == 2
    assert why in output
    assert not export.exists()


def test_console_without_a_terminal_is_refused(capsys) -> None:
    code, output = _main(["console", "/nonexistent-port"], capsys)  # pytest's stdin is no tty
    assert code == 2
    assert "needs a terminal" in output


def test_run_into_a_file_is_refused_before_the_run(tmp_path: Path, capsys) -> None:
    target = tmp_path / "a-file"
    target.write_text("not a folder\n")
    code, output = _main(["run", "thesis-6.1-pid", "--mode", "inproc", "--out", str(target)],
                         capsys)  # fmt: skip
    assert code == 2
    assert "is not a folder" in output
    assert target.read_text() == "not a folder\n"


def test_a_closed_pipe_ends_quietly() -> None:
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "sil.cli", "scenarios", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader goes away before the first line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 0
    assert "Traceback" not in err


def test_identify_refuses_time_that_does_not_increase(tmp_path: Path, capsys) -> None:
    trace = _trace(tmp_path / "trace.csv", [90.0 + i % 7 for i in range(200)],
                   [10.0 + (i // 50) for i in range(200)])  # fmt: skip
    lines = trace.read_text().splitlines()
    lines[100], lines[101] = lines[101], lines[100]  # two samples swapped: time runs back
    trace.write_text("\n".join(lines) + "\n")
    export = tmp_path / "commission.json"
    code, output = _main(["identify", str(trace), "--export", str(export)], capsys)
    assert code == 2 and not export.exists()
    assert f"{trace}, line 102: time" in output and "must increase" in output


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A short in-process run of the valid scenario: its can.log (and .asc, .blf, .mf4) and
    summary."""
    out = tmp_path_factory.mktemp("recorded")
    scenario = out / "s.toml"
    scenario.write_text(VALID.replace("duration_s = 1", "duration_s = 2"))
    argv = ["run", str(scenario), "--mode", "inproc", "--out", str(out / "run"), "--no-plots"]
    formats = ["--log-format", "asc", "--log-format", "blf", "--log-format", "mf4"]
    assert cli.main([*argv, *formats]) == 0
    return out / "run"


def _damage_bytes(data: st.DataObject, raw: bytes) -> bytes:
    kind = data.draw(st.sampled_from(["truncate", "flip", "insert", "duplicate", "garbage"]))
    if kind == "truncate":
        return raw[: data.draw(st.integers(0, len(raw)))]
    if kind == "flip":
        out = bytearray(raw)
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(out) - 1))
            out[i] ^= 1 << data.draw(st.integers(0, 7))
        return bytes(out)
    if kind == "insert":
        i = data.draw(st.integers(0, len(raw)))
        return raw[:i] + data.draw(st.binary(min_size=1, max_size=40)) + raw[i:]
    if kind == "duplicate":
        i = data.draw(st.integers(0, len(raw)))
        j = data.draw(st.integers(i, min(len(raw), i + 200)))
        return raw[:j] + raw[i:j] + raw[j:]
    return data.draw(st.binary(max_size=300))


@SETTINGS
@given(data=st.data())
def test_damaged_logs_are_read_or_refused_in_one_line(
    recorded: Path, tmp_path: Path, capsys, data
) -> None:
    name = data.draw(st.sampled_from(["can.log", "can.asc", "can.blf", "can.mf4"]))
    log = tmp_path / name
    log.write_bytes(_damage_bytes(data, (recorded / name).read_bytes()))
    export = tmp_path / "commission.json"
    export.unlink(missing_ok=True)
    command = data.draw(st.sampled_from(["replay", "identify"]))
    argv = (
        ["replay", str(log), "--dry-run"]
        if command == "replay"
        else ["identify", str(log), "--export", str(export)]
    )
    code, output = _main(argv, capsys)
    assert "Traceback" not in output
    assert code in (0, 1, 2), output
    if code == 2:
        assert str(log) in output or "sil" in output.splitlines()[-1]
        assert not export.exists()  # nothing half-written


@SETTINGS
@given(data=st.data())
def test_compare_refuses_damaged_results_in_one_line(
    recorded: Path, tmp_path: Path, capsys, data
) -> None:
    import shutil

    other = tmp_path / "other"
    shutil.rmtree(other, ignore_errors=True)
    shutil.copytree(recorded, other)
    target = other / data.draw(st.sampled_from(["summary.json", "trace.csv"]))
    target.write_bytes(_damage_bytes(data, target.read_bytes()))
    code, output = _main(["compare", str(recorded), str(other)], capsys)
    assert "Traceback" not in output
    assert code in (0, 1, 2), output


@settings(max_examples=max(10, EXAMPLES // 20), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(data=st.data())
def test_run_of_a_damaged_scenario_fails_cleanly(tmp_path: Path, capsys, data) -> None:
    import shutil

    path = tmp_path / "s.toml"
    path.write_text(_damage(data), encoding="latin-1")
    out = tmp_path / "out"
    shutil.rmtree(out, ignore_errors=True)
    argv = ["run", str(path), "--mode", "inproc", "--out", str(out), "--no-plots"]
    code, output = _main(argv, capsys)
    assert "Traceback" not in output
    assert code in (0, 1, 2), output
    if code != 0 and (out / "summary.json").exists():  # a run that ended badly says so
        import json

        assert json.loads((out / "summary.json").read_text())["status"] != "completed"
    if code == 2:
        assert not (out / "can.log").exists() and not (out / "trace.csv").exists()


def test_a_demand_the_ecu_will_not_fly_is_warned_about(tmp_path: Path, capsys) -> None:
    scenario = tmp_path / "over.toml"
    scenario.write_text(
        'duration_s = 1\n[plant]\nmodel = "fast"\n[controller]\nkind = "mrac"\n[command]\n'
        'base = 0\n[[command.component]]\nkind = "staircase"\nlevels = [90, 104, 30]\n'
        "step_s = 0.3\n"
    )
    out = tmp_path / "out"
    code, output = _main(["run", str(scenario), "--mode", "inproc", "--out", str(out),
                          "--no-plots"], capsys)  # fmt: skip
    assert code == 0
    assert "warning: over: command: demand reaches 104 %N, over the ECU's demand_max_pct" in output
    assert "demand falls to 30 %N, under the ECU's idle_pct 35" in output
    import json

    assert len(json.loads((out / "summary.json").read_text())["warnings"]) == 2


@pytest.mark.parametrize(
    ("argv", "why"),
    [
        (["plant", "--bus", "virtual:r", "--ticks", "-5"], "argument --ticks: expected a positive"),
        (
            ["plant", "--bus", "virtual:r", "--rate-hz", "0"],
            "argument --rate-hz: expected a number",
        ),
        (["plant", "--bus", "virtual:r", "--rate-hz", "300"], "does not divide the plant's 1000"),
        (
            ["plant", "--bus", "virtual:r", "--guard-s", "-1"],
            "argument --guard-s: expected a posit",
        ),
        (["ecu", "--bus", "virtual:r", "--guard", "nan"], "argument --guard: expected a finite"),
        (["ecu", "--bus", "virtual:r", "--rate", "7"], "argument --rate: expected a number in 50"),
        (["steady-line", "--out", "/dev/null/x"], "argument --out: cannot make /dev/null/x"),
    ],
)
def test_bad_option_values_are_refused_by_argparse(capsys, argv: list[str], why: str) -> None:
    code, output = _main(argv, capsys)
    assert code == 2 and why in output and "Traceback" not in output


numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -1.0, 1e-9, 0.002, 0.008, 0.012, 0.05, 230.0, 288.15, 101325.0, 5e4]),
)


@settings(max_examples=max(20, EXAMPLES // 4), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(fuel=numbers, t0=numbers, p0=numbers)
def test_trim_answers_inside_its_envelope_or_refuses(capsys, fuel: float, t0: float, p0: float):
    import json

    argv = ["trim", f"--fuel={fuel}", f"--t0={t0}", f"--p0={p0}", "--json"]
    code, output = _main(argv, capsys)
    assert "Traceback" not in output
    assert code in (0, 2), output
    if code == 0:
        state = json.loads(output)
        assert 0.0 < state["N_pct"] <= 110.0
        assert state["fuel_kg_s"] / state["air_kg_s"] <= 0.068 + 1e-9
    else:
        assert len(output.strip().splitlines()) == 1


def _split(output: str) -> list[str]:
    return [line for line in output.strip().splitlines() if line]


# -- bus specs -----------------------------------------------------------------------------------

# every python-can interface but those that make files (slcan-device links a terminal at PATH)
INTERFACES = sorted(
    can.interfaces.VALID_INTERFACES | {"udp", "socketcan", "virtual", "nonsense", "KVASER", ""}
)
channels = st.text(alphabet="abcXYZ019_.:@-", max_size=16)


@settings(max_examples=max(20, EXAMPLES // 2), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(interface=st.sampled_from(INTERFACES), channel=channels, sep=st.sampled_from([":", ""]))
def test_any_bus_spec_opens_or_is_refused_in_one_line(
    capsys, interface: str, channel: str, sep: str
) -> None:
    spec = f"{interface}{sep}{channel}"
    code = _code(["selfcheck", f"--bus={spec}"])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    assert code in (0, 2), captured.err
    if not spec:  # argparse's usage and its line
        assert _split(captured.err)[-1].endswith("argument --bus: an empty bus spec")
    elif code == 2:
        assert len(_split(captured.err)) == 1 and captured.err.startswith("sil selfcheck: ")


def _code(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:  # argparse's usage errors
        return int(exc.code or 0)


# -- campaign options and files ------------------------------------------------------------------

CAMPAIGN = """name = "fuzz"
base = "thesis-5.2-mrac-fast"
duration_s = 2
seed = 3
samples = 2

[sample]
"plant.pump_gain" = { uniform = [0.9, 1.1] }
"plant.speed_noise_rpm" = { normal = [20.0, 2.0] }
"plant.egt_noise_K" = { choice = [0.5, 1.0] }

[sweep]
"controller.kind" = ["mrac", "pid"]

[[variant]]
name = "pump"
[[variant.fault]]
time_s = 1
target = "PUMP_EFFECTIVENESS"
value = 0.5

[invariants]
max_speed_pct = 102.0
"""
CAMPAIGN_NUMBERS = ("2", "3", "0.9", "1.1", "20.0", "2.0", "0.5", "1.0", "1", "102.0")
odd_values = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "1e308", "-1e308", "1.7e308", "1e39", "0", "-1"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**20), 10**20).map(str),
)


def _damaged_campaign(data: st.DataObject) -> tuple[str, str]:
    """The campaign with one of its numbers replaced; the value put in."""
    import re

    spots = [m.span() for m in re.finditer(r"(?<![\w.])-?\d+(\.\d+)?(?![\w.])", CAMPAIGN)]
    start, end = data.draw(st.sampled_from(spots))
    value = data.draw(odd_values)
    return CAMPAIGN[:start] + value + CAMPAIGN[end:], value


def _all_finite(value: object) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_all_finite(v) for v in value)
    return True


@settings(max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(data=st.data())
def test_campaign_files_with_odd_numbers_load_or_are_refused(tmp_path: Path, data) -> None:
    import tomllib

    from sil.campaign.spec import CampaignError, load

    text, value = _damaged_campaign(data)
    path = tmp_path / "campaign.toml"
    path.write_text(text)
    try:
        campaign = load(path)
    except CampaignError as exc:
        assert str(exc).startswith(str(path)) and "\n" not in str(exc)
        return
    assert value.lstrip("-") not in ("nan", "inf"), f"{value} was accepted"
    for case in campaign.cases:  # every case a scenario with finite numbers only
        assert _all_finite(tomllib.loads(case.scenario_toml))


@settings(max_examples=max(20, EXAMPLES // 2), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(workers=st.integers(-5, 10**6))
def test_campaign_workers_are_capped(tmp_path: Path, capsys, workers: int) -> None:
    import os

    path = tmp_path / "campaign.toml"
    path.write_text(CAMPAIGN.replace('base = "thesis-5.2-mrac-fast"', 'base = "no-such"'))
    code = _code(["campaign", str(path), "--workers", str(workers), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and len(_split(err)) == 1 and "Traceback" not in err
    if 1 <= workers <= 4 * (os.cpu_count() or 1):
        assert "field 'base'" in err  # the file's error: the workers were accepted
    else:
        assert "--workers: expected a number in 1.." in err


# -- fault values --------------------------------------------------------------------------------

fault_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 0.1, 0.5, 1.0, 1.5, 100.0, 180.0, 340.0, 2147.483647, 2147.4837, 1e39]),
)


@settings(max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(
    target=st.sampled_from(fault_targets()),
    value=fault_values,
    model=st.sampled_from(["aero", "fast"]),
)
def test_fault_values_pass_only_within_the_plant_and_frame_ranges(
    tmp_path: Path, capsys, target: str, value: float, model: str
) -> None:
    from plant.faults import ENGINE_FAULTS, FAULT_TARGETS
    from sil.scenario import fault_value_range

    path = tmp_path / "s.toml"
    text = VALID.replace('model = "aero"', f'model = "{model}"')
    path.write_text(text + f"[[fault]]\ntime_s = 0.5\ntarget = '{target}'\nvalue = {value!r}\n")
    code = _code(["scenarios", "--check", str(path)])
    captured = capsys.readouterr()
    lo, hi, _ = fault_value_range(target)
    code_of_target = fault_targets().index(target)
    lacks = model == "fast" and FAULT_TARGETS.get(code_of_target) in ENGINE_FAULTS
    expected = 0 if math.isfinite(value) and lo <= value <= hi and not lacks else 2
    assert code == expected, captured.err
    if code == 2:
        assert len(_split(captured.err)) == 1 and f"{path}: field 'fault[0]." in captured.err


# -- identify --export ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def engine_trace(tmp_path_factory) -> Path:
    """60 s of the document's fast model (eq. 3.24) answering a square wave, at 100 Hz."""
    import numpy as np

    from plant.fast_model import FastEngine

    engine, rows = FastEngine(), []
    for k in range(6000):
        volts = 5.0 + (1.0 if (k // 1000) % 2 == 0 else -1.0)
        rows.append(f"{0.01 * k:.2f},{engine.n_pct!r},{volts!r}")
        engine.step(volts - 5.0, 0.01)
    path = tmp_path_factory.mktemp("identify") / "trace.csv"
    path.write_text("time,speed_meas,PumpVoltageTarget\n" + "\n".join(rows) + "\n")
    assert np.isfinite(engine.n_pct)
    return path


trims = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([89.68, 60.0, 52.0, 30.0, -5.0, 0.0, 110.0, 5.0, -12.0, 20.0, 25.0, 1.0]),
)


@settings(max_examples=max(10, EXAMPLES // 20), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(trim_n=trims, trim_v=trims)
def test_identify_exports_only_what_the_ecu_loads(
    engine_trace: Path, tmp_path: Path, capfd, trim_n: float, trim_v: float
) -> None:
    import json
    import warnings

    from sil.analysis.identify import commissioning_refusal

    export = tmp_path / "commission.json"
    export.unlink(missing_ok=True)
    argv = ["identify", str(engine_trace), f"--trim-n={trim_n}", f"--trim-v={trim_v}"]
    with warnings.catch_warnings(record=True) as warned:  # a user would see them on stderr
        warnings.simplefilter("always")
        code = _code([*argv, "--window", "51", "--export", str(export)])
    assert not [w for w in warned if issubclass(w.category, RuntimeWarning)], warned
    captured = capfd.readouterr()  # with what C code (LAPACK) prints
    assert "Traceback" not in captured.out + captured.err
    assert code in (0, 1, 2), captured.err
    said = _split(captured.err)
    if not (said and ": error: argument --trim-" in said[-1]):  # argparse's usage and its line
        assert len(said) <= 1, captured.err  # the refusal alone: no numpy warning
    if code == 0:
        assert commissioning_refusal(json.loads(export.read_text())) is None
    else:
        assert not export.exists()  # nothing half-written, nothing the ECU would refuse


# -- clear messages: bus specs, files to read, python-can's logging, fault kinds, bounds ---------


def _bus_options() -> list[tuple[list[str], str]]:
    """(the command's words, the option) for every option of every command that takes a bus
    spec, read from the parser (a new one is checked the day it is added)."""
    import argparse

    def walk(words: list[str], parser: argparse.ArgumentParser) -> list[tuple[list[str], str]]:
        found = []
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    found += walk([*words, name], sub)
            elif action.option_strings and action.dest in ("bus", "ecu_bus"):
                found.append((words, action.option_strings[-1]))
        return found

    top = cli.build_parser()
    sub = next(a for a in top._actions if a.__class__.__name__ == "_SubParsersAction")
    return [found for name, p in sorted(sub.choices.items()) for found in walk([name], p)]


BUS_OPTIONS = _bus_options()


def test_every_command_with_a_bus_is_checked():
    commands = {words[0] for words, _ in BUS_OPTIONS}
    assert {"ecu", "plant", "run", "replay", "selfcheck", "gsu", "bridge", "xcp"} <= commands


@pytest.mark.parametrize(("words", "option"), BUS_OPTIONS, ids=lambda x: " ".join(x) or x)
def test_an_empty_bus_spec_is_refused_not_taken_as_the_default(sil, words, option):
    done = sil(*words, option, "", timeout=120)
    assert done.returncode == 2 and done.stdout == "" and "Traceback" not in done.stderr
    prog = " ".join(["sil", *words])
    assert done.stderr.splitlines()[-1] == f"{prog}: error: argument {option}: an empty bus spec"


@pytest.mark.parametrize("spec", [" ", "\t", "  \n"])
def test_a_blank_bus_spec_is_refused_too(capsys, spec):
    code, output = _main(["selfcheck", "--bus", spec], capsys)
    assert code == 2 and output.splitlines()[-1].endswith("--bus: an empty bus spec")


SECRET = "sil-robustness-secret-7d41"  # put in the environment of a command given its own


# every way a `sil` command is given a file to read: IN that file, TRACE a good trace, TMP a
# scratch folder
READERS = [
    ["identify", "IN"],
    ["identify", "TRACE", "--validate", "IN"],
    ["replay", "IN", "--dry-run"],
    ["log", "convert", "IN", "TMP/o.log"],
    ["scenarios", "--check", "IN"],
    ["run", "IN", "--mode", "inproc", "--out", "TMP/out"],
    ["run", "thesis-6.1-pid", "--mode", "inproc", "--commission", "IN", "--out", "TMP/out"],
    ["campaign", "IN", "--out", "TMP/out"],
    ["bridge", "IN", "--bus", "virtual:r1", "--ecu-bus", "virtual:r2"],
    ["ecu", "--bus", "virtual:r3", "--ticks", "1", "--commission", "IN"],
    ["gsu", "--bus", "virtual:r4", "--port", "0", "--a2l", "IN"],
    ["xcp", "record", "--bus", "virtual:r5", "--a2l", "IN", "--measure", "n", "--seconds", "1",
     "--out", "TMP/o.mf4"],
]  # fmt: skip


def _reading(argv: list[str], path: str, tmp: Path) -> list[str]:
    trace = _trace(tmp / "trace.csv", [90.0 + i % 7 for i in range(50)], [10.0] * 50)
    fill = {"IN": path, "TRACE": str(trace)}
    return [fill.get(a, a.replace("TMP", str(tmp))) for a in argv]


@pytest.mark.parametrize("argv", READERS, ids=lambda argv: " ".join(argv[:2]))
def test_the_environment_as_an_input_file_is_refused_unread(sil, tmp_path, argv):
    done = sil(
        *_reading(argv, "/proc/self/environ", tmp_path),
        env={**os.environ, "SIL_ROBUSTNESS_SECRET": SECRET},
        timeout=120,
    )
    assert SECRET not in done.stdout + done.stderr and "Traceback" not in done.stderr
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines()[-1].endswith(
        "/proc/self/environ: a kernel file under /proc, not an input"
    )
    assert not (tmp_path / "out").exists() and not (tmp_path / "o.log").exists()


def _not_regular(kind: str, tmp: Path) -> tuple[str, str]:
    """A path that is no regular file (or lies in /sys), and what the refusal says of it."""
    if kind == "fifo":  # a reader would wait on it for ever
        os.mkfifo(tmp / "fifo")
        return str(tmp / "fifo"), "not a regular file (a device or a pipe)"
    if kind == "folder":
        (tmp / "folder").mkdir()
        return str(tmp / "folder"), "a folder, not a file"
    if kind == "sys":
        return (
            "/sys/kernel/mm/transparent_hugepage/enabled",
            "a kernel file under /sys, not an input",
        )
    return kind, "not a regular file (a device or a pipe)"


@pytest.mark.parametrize("kind", ["/dev/zero", "/dev/null", "fifo", "folder", "sys"])
@pytest.mark.parametrize("argv", READERS, ids=lambda argv: " ".join(argv[:2]))
def test_devices_pipes_and_folders_are_refused_as_input_files(tmp_path, capsys, kind, argv):
    path, why = _not_regular(kind, tmp_path)
    if not Path(path).exists():
        pytest.skip(f"{path} is not on this machine")
    code, output = _main(_reading(argv, path, tmp_path), capsys)
    assert code == 2 and "Traceback" not in output
    assert output.strip().splitlines()[-1].endswith(f"{path}: {why}")


ASC_DLC_MISMATCH = """date Mon Dec 7 10:00:00.000 am 2026
base hex  timestamps absolute
no internal events logged
Begin TriggerBlock Mon Dec 7 10:00:00.000 am 2026
   0.010000 CANFD   1 Rx        100  0 0 9  2 01 02   0    0   0        0        0        0        0        0
End TriggerBlock
"""  # noqa: E501 (a line as CANoe writes it)


@pytest.mark.parametrize(
    "argv",
    [["identify", "LOG"], ["replay", "LOG", "--dry-run"], ["log", "convert", "LOG", "OUT"]],
    ids=lambda argv: argv[0],
)
def test_python_can_logs_nothing_before_our_line(sil, tmp_path, argv):
    log = tmp_path / "odd.asc"
    log.write_text(ASC_DLC_MISMATCH)
    args = [str(log) if a == "LOG" else str(tmp_path / "o.log") if a == "OUT" else a for a in argv]
    done = sil(*args, timeout=120)
    assert "DLC" not in done.stderr and "Traceback" not in done.stderr
    if done.returncode == 2:  # identify: nothing to identify from, in our one line
        assert done.stderr.splitlines() == [
            f"sil identify: {log}: only 0 usable samples of time, speed and voltage"
        ]
    else:
        assert done.returncode in (0, 1) and done.stderr.strip().count("\n") == 0


# -- sil plant --fault: the scenario files' fault names ------------------------------------------


def _plant_kinds() -> list[str]:
    return [t for t in fault_targets() if t != "CLEAR_ALL"]


def _fault_text(name: str) -> str:
    """A fault of kind ``name`` (a scenario file's) at 1.5 s, with a value in its range when it
    takes one."""
    from plant.faults import FAULT_TARGETS, value_range

    kind = FAULT_TARGETS[fault_targets().index(name)]
    values = value_range(kind)
    return f"1.5:{name}" if values is None else f"1.5:{name}:{sum(values) / 2!r}"


@pytest.mark.parametrize("name", _plant_kinds())
@pytest.mark.parametrize("case", [str.upper, str.lower, str.title])
def test_plant_faults_take_the_scenario_files_names(name, case):
    from plant.faults import FAULT_TARGETS

    args = cli.build_parser(["plant"]).parse_args(["plant", "--fault", case(_fault_text(name))])
    (fault,) = args.fault
    assert fault.kind == FAULT_TARGETS[fault_targets().index(name)] and fault.at_s == 1.5


def test_an_unknown_fault_kind_lists_the_scenario_files_names(sil):
    done = sil("plant", "--fault", "3:PUMP_WEAR", timeout=120)
    assert done.returncode == 2
    last = done.stderr.splitlines()[-1]
    assert last.startswith("sil plant: error: argument --fault: fault '3:PUMP_WEAR': unknown kind")
    listed = last.split("(kinds: ")[1].rstrip(")").split(", ")
    assert set(_plant_kinds()) <= set(listed) and set(listed) - set(_plant_kinds()) == {
        "PUMP_DRY",
        "PUMP_STALL",
    }
    shown = " ".join(sil("plant", "--help", timeout=120).stdout.split())
    assert all(name in shown for name in listed)


def test_a_plant_applies_faults_named_as_in_a_scenario(sil_process, udp_spec):
    from protocol.bus import open_bus
    from protocol.dbc import load_database

    db, spec = load_database(), udp_spec()
    seen: dict[str, list[tuple[int, float]]] = {"ShaftSpeed": [], "SupplyVoltage": []}
    with open_bus(spec) as bus:
        plant = sil_process(
            "plant", "--bus", spec, "--realtime", "--ticks", "40",
            "--fault", "0.1:supply_voltage:18", "--fault", "0.2:SPEED_DROPOUT",
        )  # fmt: skip
        while (msg := bus.recv(0.1)) is not None or plant.poll() is None:
            if msg is None or msg.arbitration_id not in (0x100, 0x101):  # sensors, analog
                continue
            values = db.decode_message(msg.arbitration_id, msg.data)
            tick = values.get("SensorTick", values.get("AnalogTick"))
            for name in seen.keys() & values.keys():
                seen[name].append((tick, values[name]))
    assert plant.returncode == 0, plant.stderr.read()
    speed, supply = seen["ShaftSpeed"], seen["SupplyVoltage"]
    assert all(v > 10_000 for t, v in speed if t < 20) and all(v == 0 for t, v in speed if t > 20)
    assert all(v > 21 for t, v in supply if t < 10) and all(v < 18.5 for t, v in supply if t > 10)
    assert len(speed) > 30 and len(supply) > 6


# -- no "None" for a missing bound ---------------------------------------------------------------


@given(
    lo=st.one_of(st.none(), st.floats(-1e6, 1e6)),
    hi=st.one_of(st.none(), st.floats(-1e6, 1e6)),
    value=st.floats(allow_nan=True, allow_infinity=True),
)
def test_a_range_message_names_only_the_bounds_there_are(lo, hi, value):
    from sil.validation import InputError, number

    try:
        number("s.toml", "field 'x'", value, lo=lo, hi=hi)
    except InputError as exc:
        text = str(exc)
        assert "None" not in text and text.startswith("s.toml: field 'x': expected ")
        for bound in (lo, hi):
            if bound is not None and math.isfinite(value):
                assert f"{bound:g}" in text


@pytest.mark.parametrize(
    ("line", "expected"),
    [("time_s = -2", "a number >= 0, got -2"), ("value = nan", "a finite number, got nan")],
)
def test_a_scenario_field_out_of_range_says_its_bound_without_none(sil, tmp_path, line, expected):
    path = tmp_path / "s.toml"
    path.write_text(VALID.replace("time_s = 0.5" if "time" in line else "value = 1.0", line))
    done = sil("scenarios", "--check", str(path), timeout=120)
    assert done.returncode == 2 and "None" not in done.stderr
    assert done.stderr.splitlines() == [
        f"sil scenarios: {path}: field 'command.component[0].{line.split()[0]}': "
        f"expected {expected}"
    ]


# -- sil console: options and values ------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["--timeout", "nan", "identify"], "--timeout"),
        (["--timeout", "inf", "identify"], "--timeout"),
        (["--timeout", "0", "identify"], "--timeout"),
        (["--rate", "-1", "live"], "--rate"),
        (["live", "--samples", "0"], "--samples"),
        (["throttle", "nan"], "PCT"),
    ],
)
def test_console_options_are_refused_naming_the_option(sil, argv, option):
    done = sil("console", "/nonexistent-port", *argv, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    assert f"error: argument {option}: expected " in done.stderr.splitlines()[-1]


@settings(max_examples=max(20, EXAMPLES // 4), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(
    option=st.sampled_from(["--timeout", "--rate"]),
    value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0])),
)
def test_console_timing_options_are_finite_positive_and_bounded(capsys, option, value):
    from sil.commands.console import MAX_RATE_HZ, MAX_TIMEOUT_S

    code, output = _main(
        ["console", "/nonexistent-port", f"{option}={value!r}", "identify"], capsys
    )
    lo, hi = (0.0, MAX_TIMEOUT_S) if option == "--timeout" else (0.1, MAX_RATE_HZ)
    taken = math.isfinite(value) and (lo < value if option == "--timeout" else lo <= value)
    taken = taken and value <= hi
    if taken:  # then the port is looked for
        assert code == 2 and output.strip() == (
            "sil console: port '/nonexistent-port': cannot open it: [Errno 2] could not open "
            "port /nonexistent-port: [Errno 2] No such file or directory: '/nonexistent-port'"
        )
    else:
        assert code == 2 and f"argument {option}: expected" in output.splitlines()[-1]


def test_a_bus_whose_run_tags_are_all_taken_is_refused_in_one_line(sil, tmp_path, udp_spec):
    """As many runs on one bus as its tags keep apart: the next one says so, with no traceback,
    and its folder says why it failed."""
    from protocol.run_tag import MAX_TAG, claim_tag

    spec = udp_spec()
    scenario = tmp_path / "s.toml"
    scenario.write_text(VALID)
    claims = [claim_tag(spec) for _ in range(MAX_TAG + 1)]
    try:
        done = sil("run", str(scenario), "--bus", spec, "--out", str(tmp_path / "out"),
                   "--no-plots", timeout=120)  # fmt: skip
    finally:
        for claim in claims:
            claim.release()
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        f"sil run: bus {spec}: all {MAX_TAG + 1} run tags are in use"
    )
    assert "Traceback" not in done.stderr
    assert (tmp_path / "out" / "summary.json").exists()


@pytest.mark.parametrize("option", ["--fuel", "--t0", "--p0", "--flight-speed", "--battery-v"])
@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e400", "-1e9"])
def test_the_plants_engine_options_are_finite_and_in_a_scenarios_ranges(capsys, option, value):
    code, output = _main(["plant", option, value, "--bus", "udp:239.255.1.1@40000"], capsys)
    assert code == 2
    assert f"argument {option}: expected" in output.strip().splitlines()[-1], output
