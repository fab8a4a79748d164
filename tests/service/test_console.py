"""The interactive console's commands and screen, over loop:// against the ECU in process."""

from ecu import faults as F
from ecu.service import live, param_table
from sil.console.interactive import execute, render


def test_commands(rig):
    c = rig.client
    assert execute(c, "get pid_kp") == ["pid_kp = 2 (raw 33554432, Q frac 24)"]
    assert execute(c, "set pid_kp 2.5")[0].startswith("pid_kp = 2.5 (param CRC 0x")
    assert execute(c, "set pid_kp x") == ["error: value 'x' is not a number"]
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
