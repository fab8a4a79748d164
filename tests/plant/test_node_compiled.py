"""The plant node's compiled lockstep twin (plant.node_compiled.actuator_compiled, python_due,
advance_compiled) against PlantNode itself: the same frames out, byte for byte, and the same
state, on streams of actuator frames that answer, repeat, skip, run ahead, carry a bad CRC or an
old alive counter, switch the pump off, inject faults and drive the starter and igniter
(FaultInject and EcuStarter stay in Python; the starter's watchdog runs in both)."""

from __future__ import annotations

import random

import numpy as np
import pytest

from plant.aerothermal import AeroThermalPlant
from plant.fast_plant import FastPlant
from plant.frames import DUE_ANALOG, DUE_TRUTH, FRAMES
from plant.interface import PlantConfig
from plant.node import PlantNode
from plant.node_compiled import NF_SIZE, NS_SIZE, actuator_compiled, advance_compiled, python_due
from protocol.codec import Codec
from protocol.lockstep import TICK_MODULO

FAULT_TARGETS = (1, 2, 7, 8, 9, 10, 11, 0)  # pump effectiveness, wear, speed faults, EGT...


class Twin:
    """A PlantNode driven through the compiled functions, as sil/run/compiled_loop.py drives it."""

    def __init__(self, node: PlantNode) -> None:
        self.node = node
        self.ns, self.nf = np.zeros(NS_SIZE, np.int64), np.zeros(NF_SIZE)
        node.to_compiled(self.ns, self.nf)
        self.python_parts = 0

    def on_actuator(self, data: bytes, send) -> None:
        node, ns, nf = self.node, self.ns, self.nf
        if not actuator_compiled(ns, nf, node._layout, np.frombuffer(data, np.uint8)):
            return
        if python_due(ns, nf):
            node.from_compiled(ns, nf)
            node.python_part()
            node.to_compiled(ns, nf)
            self.python_parts += 1
        plant = node.plant
        due = advance_compiled(plant._s, plant._tables, ns, nf, node._layout, node._buf)
        for k, frame_id in enumerate(node._ids):
            if k < 3 and not due & DUE_TRUTH or k == 3 and not due & DUE_ANALOG:
                continue
            send(frame_id, node._payload[k])

    def on_python(self, frame_id: int, data: bytes, send) -> None:
        self.node.from_compiled(self.ns, self.nf)
        self.node.on_frame(frame_id, data, send)
        self.node.to_compiled(self.ns, self.nf)


def _python_run(seed: int, ticks: int, node: PlantNode):
    """Drive the node itself with events made up as it goes (mostly the answer to the tick it
    waits for, sometimes something else); returns the frames it sent and the events."""
    rng = random.Random(seed)
    codec = Codec()
    actuator, fault, starter = codec["EcuActuator"], codec["FaultInject"], codec["EcuStarter"]
    events: list[tuple[str, bytes]] = []
    sent: list[tuple[int, bytes]] = []

    def send(frame_id, data):
        sent.append((frame_id, bytes(data)))

    node.start(send)
    while node.tick < ticks:
        tick = node.tick
        r = rng.random()
        enable = 0 if rng.random() < 0.03 else 1
        duty = rng.choice((rng.randint(3000, 6000), rng.randint(-50, 10050), 10000, 0))
        if r < 0.04:  # a tick that is not this one: late, repeated or ahead (wrapping too)
            other = (tick + rng.choice((-1, -2, 1, 3, TICK_MODULO // 2 + 1))) % TICK_MODULO
            actuator.pack_raw([enable, 2, other, duty, 5000])
            event = ("act", bytes(actuator.data))
        elif r < 0.06:  # a bad CRC
            actuator.pack_raw([enable, 2, tick % TICK_MODULO, duty, 5000])
            bad = bytearray(actuator.data)
            bad[rng.randint(0, 7)] ^= 1 << rng.randint(0, 7)
            event = ("act", bytes(bad))
        elif r < 0.07:  # the previous frame again (REPEATED)
            event = ("act", bytes(actuator.data))
        elif r < 0.10:  # the starter and igniter (in bursts: the watchdog stops them between)
            starter.pack_raw([rng.randint(0, 1), tick % TICK_MODULO, rng.randint(-5, 10050), 2, 0])
            data = bytearray(starter.data)
            if rng.random() < 0.2:
                data[rng.randint(0, 7)] ^= 1 << rng.randint(0, 7)
            event = ("starter", bytes(data))
        elif r < 0.11:  # a fault for now or a few ticks ahead
            target = rng.choice(FAULT_TARGETS)
            value = rng.choice((0.0, 1.0, 0.5, 0.8, 200.0, 18.0))
            at = (tick + rng.randint(0, 6)) % TICK_MODULO
            fault.pack_raw([target, at, round(value * 1e6)])
            event = ("fault", bytes(fault.data))
        else:
            actuator.pack_raw([enable, 2, tick % TICK_MODULO, duty, 5000])
            event = ("act", bytes(actuator.data))
        if rng.random() < 0.01:  # an alive counter jump (WRONGSEQUENCE next)
            actuator.counter = (actuator.counter + 5) % 15
        events.append(event)
        kind, data = event
        node.on_frame(_ID[kind](node), data, send)
    return sent, events


_ID = {
    "act": lambda node: node._actuator_id,
    "fault": lambda node: node._fault_id,
    "starter": lambda node: node._starter_id,
}


def _twin_run(events, twin: Twin) -> list[tuple[int, bytes]]:
    sent: list[tuple[int, bytes]] = []

    def send(frame_id, data):
        sent.append((frame_id, bytes(data)))

    twin.node.start(send)
    twin.node.to_compiled(twin.ns, twin.nf)
    for kind, data in events:
        if kind == "act":
            twin.on_actuator(data, send)
        else:
            twin.on_python(_ID[kind](twin.node), data, send)
    twin.node.from_compiled(twin.ns, twin.nf)
    return sent


def _state(node: PlantNode) -> dict:
    c = node.actuator_check
    o = node.plant.outputs
    return {
        "tick": node.tick,
        "duty": node.duty,
        "pump_enabled": node.pump_enabled,
        "missed": node.missed,
        "trips": node.watchdog_trips,
        "rejected": node.actuator_rejected,
        "late": node.actuator_late,
        "ahead": node.actuator_ahead,
        "faults": (node.faults_applied, node.faults_rejected, node._pending),
        "starter": (node.starter_duty, node.igniter, node.starter_missed, node.starter_rejected),
        "checker": (c._last_counter, c.status, c.counts),
        "plant_tick": node.plant._tick,
        "outputs": (o.tick, o.flags, o.speed_rpm, o.egt_k, o.n_pct, o.pump_effectiveness),
        "state": node.plant._s.tobytes(),
    }


@pytest.mark.parametrize(
    "make,seed,ticks",
    [(FastPlant, 1, 5000), (FastPlant, 2, 3000), (AeroThermalPlant, 3, 1500)],
)
def test_compiled_twin_sends_and_keeps_what_the_node_does(make, seed, ticks):
    config = PlantConfig(seed=seed)
    python = PlantNode(make(config))
    expected, events = _python_run(seed, ticks, python)
    twin = Twin(PlantNode(make(config)))
    got = _twin_run(events, twin)
    assert len(got) == len(expected)
    for i, (a, b) in enumerate(zip(got, expected, strict=True)):
        assert a == b, f"frame {i}: compiled {a[0]:#x} {a[1].hex()} vs node {b[0]:#x} {b[1].hex()}"
    assert _state(twin.node) == _state(python)
    # the stream reached every branch (noise blocks run out every 4096 periods; faults applied)
    assert twin.python_parts > ticks // 4096 and python.faults_applied > 10
    assert python.actuator_rejected and python.actuator_late and python.actuator_ahead
    assert python.starter_rejected


def test_no_compiled_twin_in_real_time():
    node = PlantNode(FastPlant(), lockstep=False)
    assert not node.compiled()
    with pytest.raises(ValueError, match="no compiled twin"):
        node.to_compiled(np.zeros(NS_SIZE, np.int64), np.zeros(NF_SIZE))
    assert len(FRAMES) == 5
