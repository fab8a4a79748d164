"""Real SocketCAN: our codec's frames on vcan0 in a throwaway VM, candump, cantools, one bad CRC.

The host kernel has no CAN support, so tools.vcan_vm boots a VM (software emulation, about a
minute in all) where tools.vcan_probe sends the frames encoded here through python-can's socketcan
interface while ``candump -L vcan0`` captures them, then injects a good and a bad-CRC frame with
``cansend`` and runs our E2E checker on what python-can received. Back on the host, ``cantools
decode`` with our DBC must give the values encoded here. When the VM cannot start, the test fails
with the reason: it is never skipped. Leave it out with ``-m "not vcan"``.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.codec import Codec, MessageCodec
from protocol.dbc import DBC_PATH
from tools.vcan_vm import VcanVmError, run_in_vcan_vm

VM_TIMEOUT_S = 300.0
CANTOOLS = Path(sys.executable).with_name("cantools")

# Values on each signal's resolution, inside its DBC range, so the codec saturates nothing.
SENT: tuple[tuple[str, dict[str, float]], ...] = (
    ("SimRun", {"RunId": 0xC0FFEE, "RunTick": 7}),
    (
        "Demand",
        {
            "ArmRequest": 1,
            "StopRequest": 0,
            "SpeedDemand": 87.5,
            "PumpVoltageDemand": 12.345,
            "DemandTick": 42,
        },
    ),
    ("PlantSensors", {"SensorTick": 42, "ShaftSpeed": 112500, "EGT": 1030.4}),
    ("PlantSensors", {"SensorTick": 43, "ShaftSpeed": 112480, "EGT": 1030.2}),
    ("PlantAnalog", {"AnalogTick": 42, "SupplyVoltage": 24.6, "PumpCurrent": 3.125}),
    (
        "EcuActuator",
        {
            "PumpEnable": 1,
            "ActuatorMode": 2,
            "ActuatorTick": 42,
            "PumpDuty": 55.25,
            "PumpVoltageTarget": 13.2,
        },
    ),
    (
        "EcuStatus",
        {
            "EcuMode": 2,
            "FaultWord": 0x0105,
            "PumpHealth": 97.5,
            "LoopOwner": 1,
            "ReferenceSpeed": 101.25,
        },
    ),
    ("EcuTelemetry", {"TelemetryIndex": 5, "Gain_Kx1": -1.25}),
    ("FaultInject", {"FaultTarget": 1, "FaultTick": 500, "FaultValue": -0.75}),
)
# Injected with cansend twice: once as encoded (checker: OK), once with its CRC byte broken.
INJECTED = ("PlantSensors", {"SensorTick": 44, "ShaftSpeed": 112460, "EGT": 1030.0})

CAPTURE_LINE = re.compile(r"\(\d+\.\d+\) vcan0 ([0-9A-F]{3})#([0-9A-F]{16})")
DECODED_LINE = re.compile(r".* :: (\w+)\((.*)\)")


def encode(message: MessageCodec, values: dict[str, float]) -> str:
    """Pack `values` (signal name -> physical value) with our codec; the frame's bytes in hex."""
    if message.multiplexed:
        (mux_name, index), (name, value) = values.items()
        assert mux_name == message.mux_layout.name
        assert message.mux_signals[int(index)].name == name
        ordered = [index, value]
    else:
        assert set(values) == set(message.signal_names), message.name
        ordered = [values[name] for name in message.signal_names]
    assert message.pack(ordered) == 0, f"{message.name}: a value was saturated"
    return bytes(message.data).hex().upper()


def decode_capture(capture: Path) -> list[tuple[str, dict[str, float]]]:
    """`cantools decode` of a candump log: (message name, signal name -> value) per frame."""
    with capture.open("rb") as log:
        decoded = subprocess.run(
            [str(CANTOOLS), "decode", "--no-decode-choices", "--single-line", str(DBC_PATH)],
            stdin=log,
            capture_output=True,
            text=True,
            check=True,
        )
    frames = []
    for line in decoded.stdout.splitlines():
        match = DECODED_LINE.fullmatch(line)
        assert match, f"cantools decode could not decode: {line}"
        signals = (field.split(": ") for field in match.group(2).split(", "))
        frames.append((match.group(1), {name: float(text.split()[0]) for name, text in signals}))
    return frames


@pytest.mark.vcan
@pytest.mark.slow
def test_codec_frames_on_real_vcan0(tmp_path: Path) -> None:
    codec = Codec()
    plan_frames = [
        {"frame_id": codec[name].frame_id, "data": encode(codec[name], values)}
        for name, values in SENT
    ]
    injected = codec[INJECTED[0]]
    good = encode(injected, INJECTED[1])
    bad = f"{int(good[:2], 16) ^ 0xFF:02X}{good[2:]}"
    plan = {
        "frames": plan_frames,
        "inject": {
            "frame_id": injected.frame_id,
            "data_id": injected.data_id,
            "frames": [good, bad],
        },
    }
    (tmp_path / "plan.json").write_text(json.dumps(plan, indent=1))

    command = shlex.join([sys.executable, "-m", "tools.vcan_probe", str(tmp_path)])
    try:
        run = run_in_vcan_vm(command, rwdir=tmp_path, timeout_s=VM_TIMEOUT_S)
    except VcanVmError as error:
        pytest.fail(f"the vcan VM did not run the probe: {error}")
    print(f"vcan VM: vcan0 up after {run.boot_s:.1f} s, whole run {run.wall_s:.1f} s")
    assert run.returncode == 0, f"probe failed in the VM (exit {run.returncode}):\n{run.output}"

    # candump saw exactly the bytes sent, in order: ours through python-can, then the injected.
    capture = tmp_path / "capture.log"
    captured = [
        match.groups() if (match := CAPTURE_LINE.fullmatch(line)) else line
        for line in capture.read_text().splitlines()
    ]
    expected_raw = [(f"{f['frame_id']:03X}", f["data"]) for f in plan_frames]
    expected_raw += [(f"{injected.frame_id:03X}", data) for data in (good, bad)]
    assert captured == expected_raw

    # cantools, reading the capture with our DBC, gives back the values encoded.
    expected = [*SENT, INJECTED, INJECTED]
    decoded = decode_capture(capture)
    assert [name for name, _ in decoded] == [name for name, _ in expected]
    for (name, values), (_, got) in zip(expected, decoded, strict=True):
        assert {k: got[k] for k in values} == pytest.approx(values, rel=1e-9, abs=1e-9), name

    # The injected frames reached python-can unchanged; the checker accepts the good one and
    # reports the broken CRC.
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["received"] == [good, bad]
    assert result["verdicts"] == ["OK", "WRONGCRC"]
