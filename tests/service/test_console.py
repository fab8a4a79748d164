"""The interactive console's commands and screen, the logbook and the checks of a value to set,
over loop:// against the ECU in process."""

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu import faults as F
from ecu.service import live, param_table
from sil.console.client import ServiceRequestError
from sil.console.interactive import execute, render


def test_commands(rig):
    c = rig.client
    assert execute(c, "get pid_kp") == ["pid_kp = 2 (raw 33554432, Q frac 24)"]
    assert execute(c, "set pid_kp 2.5")[0].startswith("pid_kp = 2.5 (param CRC 0x")
    assert execute(c, "set pid_kp x") == ["error: set pid_kp: 'x' is not a number"]
    assert execute(c, "set pid_kp 30") == [
        "error: PARAM_WRITE: OUT_OF_RANGE: pid_kp=30 V/%N: outside its limits [0, 20]"
    ]
    params = execute(c, "params")
    assert len(params) == len(param_table.TABLE) and params[0].split()[:2] == ["pid_kp", "2.5"]
    assert any(line.startswith("trim_v") and line.endswith("(not in RUN)") for line in params)
    assert execute(c, "save") == [
        "error: PARAM_SAVE: STORAGE: no flash image (start the ECU with --flash FILE)"
    ]
    rig.ticks(3)
    logged = execute(c, "faults")
    assert logged[0].split()[2] == "SENSOR_FRAME_LOST"
    assert execute(c, "clear") == [f"cleared {len(logged)} entries"]
    assert execute(c, "faults") == ["fault log empty"]
    assert execute(c, "stop") == ["stop requested (mode was OFF)"]
    assert execute(c, "rate 25") == ["streaming at 25 Hz"]
    assert execute(c, "nonsense")[0].startswith("commands: arm | throttle PCT")
    assert execute(c, 'get "unclosed') == ["error: No closing quotation"]
    assert execute(c, "") == []


def test_screen_shows_the_live_sample(rig):
    rig.engine_running()
    rig.client.stream(100)
    rig.ticks(5)
    rig.client.receive()
    lines = render(rig.client.identify(), rig.client.latest(), rig.client.stream_gaps)
    assert lines[0].startswith("turbojet-ecu 0.1  build ")
    assert lines[2].startswith("mode RUN")
    assert "speed   89.68 %N  (100890 rpm)" in lines[3]
    assert lines[-1] == "faults: none"
    raw = list(rig.client.samples[-1])
    raw[live.NAMES.index("fault_word")] = F.EGT_OPEN | F.PUMP_DRY
    lines = render(rig.client.identify(), live.decode(raw), 0)
    assert lines[-1] == "faults: EGT_OPEN, PUMP_DRY"
    assert render(rig.client.identify(), None, 0)[-1] == "waiting for live data..."


def test_the_logbook_is_shown_by_name_in_its_units(rig):
    s = rig.ecu.s
    s.log_runs, s.log_run_time_s, s.log_run_frac_ticks, s.log_starts = 7, 3601, 42, 9
    s.log_aborts[2] = 3  # the third reason: STARTER_FAILURE
    s.log_last_max_egt_dk, s.log_last_max_speed_cpct = 10_327, 10_105
    s.log_last_shutdown = 3  # FLAMEOUT
    rows = {r["name"]: (r["value"], r["unit"]) for r in rig.client.logbook()}
    assert len(rows) == 13
    assert rows["log_runs"] == (7, "") and rows["log_starts"] == (9, "")
    assert rows["log_run_time_s"] == (3601, "s") and rows["log_run_frac_ticks"] == (42, "ticks")
    assert rows["log_aborts_starter_failure"] == (3, "")
    assert rows["log_aborts_ignition_timeout"] == (0, "")
    assert rows["log_last_max_egt"] == (1032.7, "K")
    assert rows["log_last_max_speed"] == (101.05, "%N")
    assert rows["log_last_shutdown"] == ("FLAMEOUT", "")
    lines = execute(rig.client, "logbook")
    assert len(lines) == 13 and lines[-3].split() == ["log_last_max_egt", "1032.7", "K"]


@pytest.mark.parametrize("value", ["nan", "-inf", "inf", "1e400", "1e300", "-3e9", "x", "0x"])
def test_a_value_no_finite_number_or_beyond_its_q_format_names_the_parameter(rig, value):
    before = rig.client.get("pid_kp")["raw"]
    (line,) = execute(rig.client, f"set pid_kp {value}")
    assert line.startswith("error: set pid_kp: ") and "None" not in line
    assert rig.client.get("pid_kp")["raw"] == before  # nothing was written


@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(value=st.floats(allow_nan=True, allow_infinity=True))
def test_any_float_is_written_within_its_q_format_or_refused_by_name(rig, value):
    frac = rig.client.get("pid_kp")["frac"]
    top = (1 << 31) / (1 << frac)
    try:
        written = rig.client.set("pid_kp", value)
    except ValueError as exc:
        assert str(exc).startswith("set pid_kp: ")
        assert not -(1 << 31) <= value * (1 << frac) <= (1 << 31) - 1  # (NaN too)
        return
    except ServiceRequestError as exc:  # the ECU's own limits: [0, 20]
        assert "OUT_OF_RANGE: pid_kp=" in str(exc) and abs(value) < top
        return
    assert 0 <= round(value * (1 << frac)) <= 20 << frac  # limits of the raw value written
    assert abs(written["value"] - value) <= 1 / (1 << frac)
