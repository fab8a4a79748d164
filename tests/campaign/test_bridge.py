"""The injector as a real-time bridge between two python-can (virtual) buses."""

import math
import time

import can
from e2e.p01 import e2e_p01_check

from protocol.codec import Codec
from sil.busfault.bridge import Bridge
from sil.busfault.injector import Injector
from sil.busfault.spec import BusFault

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
