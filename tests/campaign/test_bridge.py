"""The injector as a bridge between two python-can buses, by the wall clock and in lockstep."""

import json
import math
import subprocess
import sys
import time
from dataclasses import replace

import can
import pytest
from e2e.p01 import e2e_p01_check

from protocol.bus import BusSpecError, open_bus, unique_udp_spec
from protocol.codec import Codec
from sil import scenario as scenarios
from sil.busfault.bridge import Bridge, SensorTicks
from sil.busfault.injector import Injector
from sil.busfault.spec import BusFault
from sil.run.runner import RunOptions, run

CODEC = Codec()
SENSORS = CODEC["PlantSensors"]


def pair(name: str) -> tuple[can.BusABC, can.BusABC]:
    return (
        can.Bus(interface="virtual", channel=name, receive_own_messages=False),
        can.Bus(interface="virtual", channel=name, receive_own_messages=False),
    )


def received(bus: can.BusABC, wait_s: float = 0.5) -> list[can.Message]:
    out = []
    while (msg := bus.recv(wait_s)) is not None:
        out.append(msg)
    return out


def test_bridge_drops_at_its_rate_flips_bits_and_passes_the_rest_both_ways():
    faults = (
        BusFault("drop", (SENSORS.frame_id,), 0.0, 100.0, rate=0.3),
        BusFault("bitflip", (CODEC["EcuActuator"].frame_id,), 0.0, 100.0, rate=1.0),
    )
    node_a, bridge_a = pair("bridge-test-a")
    node_b, bridge_b = pair("bridge-test-b")
    bridge = Bridge(bridge_a, bridge_b, Injector(faults, 100.0, 1, CODEC))
    n = 1000
    with bridge:
        for k in range(n):
            SENSORS.pack_raw([k, 90_000, 10_000])
            node_a.send(can.Message(arbitration_id=0x100, data=SENSORS.data, is_extended_id=False))
        actuator = CODEC["EcuActuator"]
        for k in range(50):
            actuator.pack_raw([1, 2, k, 5000, 11_000])
            node_b.send(can.Message(arbitration_id=0x110, data=actuator.data, is_extended_id=False))
        through_b, through_a = received(node_b), received(node_a)
    sigma = math.sqrt(n * 0.3 * 0.7)
    assert abs(len(through_b) - n * 0.7) < 4.5 * sigma
    assert len(through_a) == 50
    assert bridge.forwarded == [50, len(through_b)]
    assert not any(e2e_p01_check(bytearray(m.data), actuator.data_id) for m in through_a)
    for bus in (node_a, node_b, bridge_a, bridge_b):
        bus.shutdown()


def test_bridge_delays_frames_by_ticks_of_the_wall_clock():
    node_a, bridge_a = pair("bridge-delay-a")
    node_b, bridge_b = pair("bridge-delay-b")
    fault = BusFault("delay", (0x100,), 0.0, 100.0, delay_ticks=20)  # 20 ticks of 10 ms
    with Bridge(bridge_a, bridge_b, Injector((fault,), 100.0, 1, CODEC)):
        t0 = time.monotonic()
        node_a.send(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
        msg = node_b.recv(2.0)
        lag = time.monotonic() - t0
    assert msg is not None and 0.18 <= lag < 0.5
    for bus in (node_a, node_b, bridge_a, bridge_b):
        bus.shutdown()


def test_sensor_ticks_follow_plant_sensors_and_release_delayed_frames_before_the_new_tick():
    node_a, bridge_a = pair("bridge-lockstep-a")
    node_b, bridge_b = pair("bridge-lockstep-b")
    actuator = CODEC["EcuActuator"]
    fault = BusFault("delay", (actuator.frame_id,), 0.0, 100.0, delay_ticks=2)
    ticks = SensorTicks()
    with Bridge(bridge_a, bridge_b, Injector((fault,), 100.0, 1, CODEC), ticks=ticks):
        for k in range(6):
            SENSORS.pack_raw([k, 90_000, 10_000])
            node_a.send(can.Message(arbitration_id=0x100, data=SENSORS.data, is_extended_id=False))
            assert node_b.recv(1.0).data[2] == k  # sensors(k) reached the ECU's side
            if k == 1:  # the ECU's answer to tick 1 is held until tick 3 begins
                actuator.pack_raw([1, 2, k, 5000, 11_000])
                msg = can.Message(arbitration_id=0x110, data=actuator.data, is_extended_id=False)
                node_b.send(msg)
                time.sleep(0.1)
            got = node_a.recv(0.1)
            assert (got is not None) == (k == 3), f"tick {k}: {got}"
        assert ticks.now() == 5
    ticks.observe(0x100, bytes([0, 0, 0xFF, 0xFF, 0, 0, 0, 0]))  # 65535: an older tick
    assert ticks.now() == 5
    ticks.tick = 65_534
    ticks.observe(0x100, bytes([0, 0, 1, 0, 0, 0, 0, 0]))  # wraps: 65536 + 1
    assert ticks.now() == 65_537
    for bus in (node_a, node_b, bridge_a, bridge_b):
        bus.shutdown()


FLIPPED = """
duration_s = 3
seed = 4
[plant]
model = "fast"
[controller]
preset = "default"
[command]
base = 85
[[bus_fault]]
kind = "bitflip"
ids = ["PlantSensors"]
start_s = 1
duration_s = 1
rate = 0.3
bits = 2
"""


def test_lockstep_run_through_the_bridge_matches_the_inproc_run(tmp_path):
    """Bit flips on the plant's sensor frames between two udp buses: the ECU behind the bridge
    does what it does in process, so can.log (recorded on the plant's side) is the same bytes."""
    path = tmp_path / "flipped.toml"
    path.write_text(FLIPPED)
    s = scenarios.load(path)
    inproc = run(RunOptions(s, tmp_path / "inproc", mode="inproc", plots=False, progress=False))
    bridged = run(RunOptions(s, tmp_path / "bus", bus="udp", plots=False, progress=False))
    assert bridged["status"] == "completed" and bridged["missed_ticks"] == 0
    assert bridged["ecu_bus"].startswith("udp:") and bridged["ecu_bus"] != bridged["bus"]
    flips = inproc["bus_faults_injected"]
    assert len(flips) > 10 and all(e.pop("e2e") == "WRONGCRC" for e in flips)
    assert bridged["bus_faults_injected"] == flips
    assert "SENSOR_FRAME_LOST" in {f["fault"] for f in bridged["faults"]}
    assert (tmp_path / "bus" / "can.log").read_bytes() == (
        tmp_path / "inproc" / "can.log"
    ).read_bytes()


def test_bus_faults_on_a_bus_without_a_second_one_are_refused(tmp_path):
    path = tmp_path / "flipped.toml"
    path.write_text(FLIPPED)
    s = scenarios.load(path)
    with pytest.raises(BusSpecError, match="need a second bus for the ECU.*--ecu-bus"):
        run(RunOptions(s, tmp_path / "a", bus="virtual:x", plots=False, progress=False))
    with pytest.raises(BusSpecError, match="is the run's bus"):
        opts = RunOptions(s, tmp_path / "b", bus="udp:239.255.9.9@40000", plots=False)
        run(replace(opts, ecu_bus="udp:239.255.9.9@40000", progress=False))


BRIDGE_FAULTS = """
seed = 3
[[bus_fault]]
kind = "drop"
ids = ["PlantSensors"]
start_s = 0
duration_s = 1000
"""


def test_sil_bridge_command_between_two_udp_buses(tmp_path):
    faults, events = tmp_path / "faults.toml", tmp_path / "events.json"
    faults.write_text(BRIDGE_FAULTS)
    plant_spec, ecu_spec = unique_udp_spec(), unique_udp_spec()
    cmd = [sys.executable, "-m", "sil.cli", "bridge", str(faults), "--bus", str(plant_spec)]
    cmd += ["--ecu-bus", str(ecu_spec), "--duration", "4", "--events", str(events), "--json"]
    with open_bus(plant_spec) as plant, open_bus(ecu_spec) as ecu:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert "faults" in proc.stderr.readline()  # the bridge is up
        for k in range(20):
            SENSORS.pack_raw([k, 90_000, 10_000])
            plant.send(can.Message(arbitration_id=0x100, data=SENSORS.data, is_extended_id=False))
            plant.send(can.Message(arbitration_id=0x80, data=bytes(8), is_extended_id=False))
        heard = received(ecu, 0.5)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert [m.arbitration_id for m in heard] == [0x80] * 20
    summary = json.loads(out)
    assert (summary["forwarded_to_ecu_side"], summary["events"]) == (20, 20)
    assert {e["action"] for e in json.loads(events.read_text())} == {"dropped"}


def test_sil_bridge_refuses_a_bad_fault_file_naming_the_field(tmp_path):
    faults = tmp_path / "faults.toml"
    faults.write_text(BRIDGE_FAULTS.replace('"drop"', '"lose"'))
    cmd = [sys.executable, "-m", "sil.cli", "bridge", str(faults), "--bus", "udp"]
    done = subprocess.run([*cmd, "--ecu-bus", "udp"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 2
    assert f"{faults}: field 'bus_fault[0].kind'" in done.stderr
