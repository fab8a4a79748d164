"""A node behind a pseudo-terminal speaking slcan, as a USB-CAN adapter (or an MCU's UART) would
be, driven through python-can's own ``slcan`` interface."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.bus import open_bus
from protocol.slcan_device import SlcanError, decode, encode

frames = st.builds(
    lambda ext, frame_id, data: can.Message(
        arbitration_id=frame_id & ((1 << 29) - 1 if ext else 0x7FF),
        is_extended_id=ext,
        data=data,
    ),
    st.booleans(),
    st.integers(0, (1 << 29) - 1),
    st.binary(min_size=0, max_size=8),
)


@pytest.fixture(scope="module")
def adapter(tmp_path_factory):
    """The device end and python-can's slcan host on its terminal."""
    link = tmp_path_factory.mktemp("slcan") / "ecu.tty"
    device = open_bus(f"slcan-device:{link}")
    host = can.Bus(interface="slcan", channel=str(link), bitrate=500_000, sleep_after_open=0)
    yield device, host
    host.shutdown()
    device.shutdown()
    assert not link.exists()  # the link goes with the device


def _same(a: can.Message | None, b: can.Message) -> bool:
    return a is not None and (a.arbitration_id, a.is_extended_id, bytes(a.data)) == (
        b.arbitration_id,
        b.is_extended_id,
        bytes(b.data),
    )


@settings(max_examples=60, deadline=None)
@given(frames)
def test_frames_cross_both_ways_as_python_can_sees_them(adapter, msg):
    device, host = adapter
    host.send(msg)
    assert _same(device.recv(1.0), msg)
    device.send(msg)
    assert _same(host.recv(1.0), msg)


@given(frames)
def test_encode_decode_round_trip(msg):
    assert _same(decode(encode(msg)[:-1]), msg)


@pytest.mark.parametrize("line", [b"t12", b"t1239", b"t123201", b"T1FFFFFFFF0", b"tXYZ0"])
def test_damaged_frame_lines_are_refused(line):
    with pytest.raises(SlcanError, match="not an slcan frame"):
        decode(line)


def test_unknown_commands_get_bel_and_are_counted(adapter):
    device, host = adapter
    before = device.bad_lines
    host.serialPortOrig.write(b"q\rt12\r")  # an unknown command and a short frame line
    host.serialPortOrig.write(b"t1231AA\r")
    assert _same(
        device.recv(1.0), can.Message(arbitration_id=0x123, data=b"\xaa", is_extended_id=False)
    )
    assert device.bad_lines == before + 2


def _pair(bus_ecu: str, bus_plant: str, tmp: Path, ticks: int) -> tuple[dict, dict]:
    """`sil ecu` and `sil plant` in lockstep for `ticks` plant periods; their summaries."""
    ready, ecu_json, plant_json = tmp / "ready", tmp / "ecu.json", tmp / "plant.json"
    sil = [sys.executable, "-m", "sil.cli"]
    ecu = subprocess.Popen(
        [*sil, "ecu", "--bus", bus_ecu, "--mode", "lockstep", "--ready-file", str(ready),
         "--stats-file", str(ecu_json)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not ready.exists():
            assert ecu.poll() is None and time.monotonic() < deadline, ecu.stderr.read()
            time.sleep(0.05)
        plant = subprocess.run(
            [*sil, "plant", "--bus", bus_plant, "--ticks", str(ticks),
             "--stats-file", str(plant_json)],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert plant.returncode == 0, plant.stderr
    finally:
        ecu.terminate()  # SIGTERM: the ECU ends with its summary
        ecu.wait(20)
    return json.loads(ecu_json.read_text()), json.loads(plant_json.read_text())


def test_a_lockstep_plant_flies_the_ecu_through_the_adapter_as_over_a_bus(tmp_path):
    link = tmp_path / "ecu.tty"
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    ecu_a, plant_a = _pair(f"slcan-device:{link}", f"slcan:{link}", tmp_path / "a", 200)
    port = 20000 + os.getpid() % 30000
    udp = f"udp:239.255.77.{os.getpid() % 250 + 1}@{port}"
    ecu_b, plant_b = _pair(udp, udp, tmp_path / "b", 200)
    for key in ("frames_received", "frames_sent", "guard_timeouts"):
        assert plant_a[key] == plant_b[key], key  # the plant saw the same exchange
    assert plant_a["guard_timeouts"] == 0
    assert ecu_a["ticks"] == ecu_b["ticks"] >= 200
    assert ecu_a["frames_sent"] == ecu_b["frames_sent"]
