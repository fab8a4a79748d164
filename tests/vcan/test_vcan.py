"""Real SocketCAN in a throwaway VM: our codec's frames, one bad CRC, and a lockstep SIL run.

The host kernel has no CAN support, so tools.vcan_vm boots one VM (software emulation) for the
module, in which

1. tools.vcan_probe sends the frames encoded here through python-can's socketcan interface while
   ``candump -L vcan0`` captures them, then injects a good and a bad-CRC frame with ``cansend``
   and runs our E2E checker on what python-can received. Back on the host, ``cantools decode``
   with our DBC must give the values encoded here.
2. A 5 s lockstep scenario (MRAC on the fast model) runs as plant and ECU processes on
   ``socketcan:vcan0`` while ``candump -L vcan0`` captures the bus; ``cantools decode`` of the
   capture must agree with the run's can.log, which must equal the host's in-process run of the
   same scenario byte for byte. The plant's compiled code comes from a numba cache written on the
   host for a generic CPU (compiling it under emulation would take many minutes).

When the VM cannot start, the tests fail with the reason: they are never skipped. Leave them out
with ``-m "not vcan"``. The whole module takes 10 to 15 minutes of one core, most of it Python
starting its processes in the guest (software emulation, the host's files shared over 9p); the
suite runs it first, beside the other tests.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from protocol.codec import Codec, MessageCodec
from protocol.dbc import DBC_PATH
from sil.scenario import SCENARIO_DIR
from tools.vcan_vm import VcanVmError, VmResult, run_in_vcan_vm

VM_TIMEOUT_S = 1200.0
CANTOOLS = Path(sys.executable).with_name("cantools")
SIL_SCENARIO = "thesis-5.2-mrac-fast"
SIL_DURATION_S = 5  # 500 ticks: every frame of the run's schedule, many times over
PAIR_DURATION_S = 5  # two runs at once on vcan0, each kept apart by its run tag
# The plant's numba code, compiled on the host for a CPU that the emulated guest also has.
NUMBA_ENV = {"NUMBA_CPU_NAME": "generic"}

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
            "SensorsValid": 1,
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


@dataclass
class VmRun:
    folder: Path
    result: VmResult
    plan_frames: list[dict]
    good: str
    bad: str


def _plan(folder: Path) -> tuple[list[dict], str, str]:
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
    (folder / "plan.json").write_text(json.dumps(plan, indent=1))
    return plan_frames, good, bad


def _sil_scenario(folder: Path, seconds: int = SIL_DURATION_S) -> Path:
    text = (SCENARIO_DIR / f"{SIL_SCENARIO}.toml").read_text()
    text, count = re.subn(r"(?m)^duration_s = .*$", f"duration_s = {seconds}", text)
    assert count == 1
    path = folder / f"{SIL_SCENARIO}-{seconds}s.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def vm_run(tmp_path_factory: pytest.TempPathFactory) -> VmRun:
    folder = tmp_path_factory.mktemp("vcan")
    plan_frames, good, bad = _plan(folder)
    scenario = _sil_scenario(folder)
    short = _sil_scenario(folder, PAIR_DURATION_S)
    env = {**NUMBA_ENV, "NUMBA_CACHE_DIR": str(folder / "numba")}
    run = [sys.executable, "-m", "sil.cli", "run"]
    sil = [*run, str(scenario), "--no-plots"]
    # on the host, in one process: the reference can.logs, and the numba cache for the guest
    for path, out in ((scenario, "host"), (short, "host-short")):
        host = subprocess.run(
            [*run, str(path), "--no-plots", "--mode", "inproc", "--out", str(folder / out)],
            env={**os.environ, **env},
            capture_output=True,
            text=True,
        )
        assert host.returncode == 0, host.stderr
    env_words = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items())
    pair = [*run, str(short), "--no-plots", "--bus", "socketcan:vcan0", "--out"]
    probe = [sys.executable, "-m", "tools.vcan_probe"]
    guest = " ".join(
        [
            f"{shlex.join([*probe, str(folder)])} > {folder}/probe.out 2>&1;",
            f"echo $? > {folder}/probe.status;",
            f"{' '.join(f'{k}={shlex.quote(v)}' for k, v in env.items())}",
            shlex.join(
                [
                    *probe,
                    "--capture",
                    str(folder / "sil-capture.log"),
                    "--",
                    *sil,
                    "--bus",
                    "socketcan:vcan0",
                    "--out",
                    str(folder / "sil"),
                ]
            ),
            f"> {folder}/sil.out 2>&1;",
            f"echo $? > {folder}/sil.status;",
            *(
                f"{env_words} {shlex.join([*pair, str(folder / f'pair-{x}')])}"
                f" > {folder}/pair-{x}.out 2>&1 & {x}=$!;"
                for x in "ab"
            ),
            f"wait $a; ra=$?; wait $b; rb=$?; echo $((ra | rb)) > {folder}/pair.status",
        ]
    )
    try:
        result = run_in_vcan_vm(guest, rwdir=folder, timeout_s=VM_TIMEOUT_S)
    except VcanVmError as error:
        pytest.fail(f"the vcan VM did not run the probe: {error}")
    print(f"vcan VM: vcan0 up after {result.boot_s:.1f} s, whole run {result.wall_s:.1f} s")
    return VmRun(folder, result, plan_frames, good, bad)


def _guest_status(run: VmRun, step: str) -> None:
    status = run.folder / f"{step}.status"
    output = run.folder / f"{step}.out"
    assert status.exists(), f"{step} did not run in the VM:\n{run.result.output}"
    log = output.read_text() if output.exists() else ""
    assert status.read_text().strip() == "0", f"{step} failed in the VM:\n{log}"


@pytest.mark.vcan
@pytest.mark.timeout(VM_TIMEOUT_S + 300)  # the VM's own limit first, with the set-up
@pytest.mark.slow
def test_codec_frames_on_real_vcan0(vm_run: VmRun) -> None:
    _guest_status(vm_run, "probe")
    tmp_path, plan_frames, good, bad = vm_run.folder, vm_run.plan_frames, vm_run.good, vm_run.bad
    injected = Codec()[INJECTED[0]]

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


def _frames(log: Path) -> list[tuple[str, str]]:
    """(ID, data) of every frame of a candump -L log, in order."""
    frames = []
    for number, line in enumerate(log.read_text().splitlines(), 1):
        match = re.fullmatch(r"\(\d+\.\d+\) \w+ ([0-9A-F]{3})#([0-9A-F]*)", line)
        assert match, f"{log.name} line {number}: not a candump -L frame: {line!r}"
        frames.append((match.group(1), match.group(2)))
    return frames


@pytest.mark.vcan
@pytest.mark.timeout(VM_TIMEOUT_S + 300)  # the VM's own limit first, with the set-up
@pytest.mark.slow
def test_lockstep_sil_on_real_vcan0(vm_run: VmRun) -> None:
    _guest_status(vm_run, "sil")
    run = vm_run.folder / "sil"
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["bus"] == "socketcan:vcan0"
    assert summary["sim_time_s"] == pytest.approx(SIL_DURATION_S, abs=0.02)
    assert summary["missed_ticks"] == 0
    print(f"SIL on vcan0 in the VM: {summary['wall_time_s']:.0f} s for {SIL_DURATION_S} s")

    # The same frames as the host's in-process run, byte for byte (timestamps are sim time).
    can_log = (run / "can.log").read_text().splitlines()
    host_log = (vm_run.folder / "host" / "can.log").read_text().splitlines()
    pairs = enumerate(zip(can_log, host_log, strict=False))
    line = next((i for i, (a, b) in pairs if a != b), None)
    assert line is None, f"line {line + 1}: {can_log[line]} != {host_log[line]}"
    assert len(can_log) == len(host_log)

    # candump saw what the recorder wrote: the capture's frames, up to the last one recorded,
    # are can.log's (the recorder orders each tick's frames by sender; candump by arrival). The
    # plant's frames after the recorder stopped are the only extra ones, but for the command
    # node's SimRun beacons (the run's, not recorded).
    recorded = _frames(run / "can.log")
    captured = _frames(vm_run.folder / "sil-capture.log")
    simrun = f"{Codec()['SimRun'].frame_id:03X}"
    assert any(frame_id == simrun for frame_id, _ in captured)
    captured = [frame for frame in captured if frame[0] != simrun]
    assert len(captured) >= len(recorded)
    assert Counter(captured[: len(recorded)]) == Counter(recorded)
    assert len(captured) - len(recorded) < 20

    # cantools decodes that part of the capture to what it decodes from can.log.
    head = vm_run.folder / "capture-head.log"
    head.write_text("".join(f"(0.0) vcan0 {i}#{d}\n" for i, d in captured[: len(recorded)]))
    key = lambda item: (item[0], sorted(item[1].items()))  # noqa: E731
    from_capture = sorted(decode_capture(head), key=key)
    from_log = sorted(decode_capture(run / "can.log"), key=key)
    assert len(from_capture) == len(recorded)
    assert from_capture == from_log


@pytest.mark.vcan
@pytest.mark.timeout(VM_TIMEOUT_S + 300)  # the VM's own limit first, with the set-up
@pytest.mark.slow
def test_two_runs_at_once_on_real_vcan0_keep_apart(vm_run: VmRun) -> None:
    status = vm_run.folder / "pair.status"
    logs = "".join(
        (vm_run.folder / f"pair-{x}.out").read_text()
        for x in "ab"
        if (vm_run.folder / f"pair-{x}.out").exists()
    )
    assert status.exists() and status.read_text().strip() == "0", logs
    host_log = (vm_run.folder / "host-short" / "can.log").read_text()
    summaries = [
        json.loads((vm_run.folder / f"pair-{x}" / "summary.json").read_text()) for x in "ab"
    ]
    for x, summary in zip("ab", summaries, strict=True):
        assert summary["status"] == "completed" and summary["missed_ticks"] == 0, x
        assert (vm_run.folder / f"pair-{x}" / "can.log").read_text() == host_log, x
    assert sorted(s["run_tag"] for s in summaries) == [0, 1]
    assert all(s["foreign_frames"] > 0 and s["foreign_runs"] == 1 for s in summaries)
