"""The plant as a CAN node: lockstep, watchdog, fault injection, over the protocol codec."""

from __future__ import annotations

import threading

import can
import pytest

from plant import flags as fl
from plant.fast_plant import FastPlant
from plant.faults import Fault, FaultKind
from plant.interface import PlantConfig
from plant.node import PlantNode
from protocol.codec import Codec
from protocol.node import InProcessBus, run_lockstep


class FakeEcu:
    """Answers each PlantSensors frame with EcuActuator echoing its tick (or not, when mute)."""

    def __init__(self, duty: float, ticks: int) -> None:
        codec = Codec()
        self.sensors, self.actuator, self.fault = (
            codec["PlantSensors"],
            codec["EcuActuator"],
            codec["FaultInject"],
        )
        self.duty, self.ticks = duty, ticks
        self.seen: list[tuple[int, int, int]] = []
        self.mute_from = None
        self.inject: dict[int, tuple[int, int, float]] = {}  # at sensor tick: fault frame
        self.finished = False

    def start(self, send):
        pass

    def on_frame(self, frame_id, data, send):
        if frame_id != self.sensors.frame_id:
            return
        raw = [0, 0, 0]
        self.sensors.unpack_raw(data, raw)
        self.seen.append(tuple(raw))
        tick = raw[0]
        if tick in self.inject:
            target, fault_tick, value = self.inject[tick]
            self.fault.pack_raw([target, fault_tick, round(value * 1e6)])
            send(self.fault.frame_id, self.fault.data)
        if len(self.seen) > self.ticks:
            self.finished = True
            return
        if self.mute_from is not None and tick >= self.mute_from:
            return
        self.actuator.pack_raw([1, 2, tick, round(self.duty * 1e4), 0])
        send(self.actuator.frame_id, self.actuator.data)

    def on_timeout(self, send):
        pass


@pytest.fixture(scope="module")
def fast():
    return FastPlant()


def _run(node, ecu):
    InProcessBus([node, ecu]).run(done=lambda: ecu.finished)


def test_lockstep_one_period_per_answered_tick(fast):
    node = PlantNode(FastPlant())
    ecu = FakeEcu(node.plant.trim_duty, 50)
    _run(node, ecu)
    assert [s[0] for s in ecu.seen] == list(range(51))
    assert node.tick == 50 and node.plant.time_s == pytest.approx(0.5)
    assert node.missed == 0 and node.watchdog_trips == 0
    assert ecu.seen[-1][1] == pytest.approx(node.plant.outputs.speed_rpm, abs=1)
    assert ecu.seen[-1][2] == round(node.plant.outputs.egt_k * 10)


def test_wrong_tick_or_bad_crc_does_not_advance_time():
    node = PlantNode(FastPlant())
    codec = Codec()
    act = codec["EcuActuator"]
    sent = []

    def send(frame_id, data):
        sent.append(frame_id)

    node.start(send)
    act.pack_raw([1, 2, 5, 5000, 0])  # answers a tick that is not the current one
    node.on_frame(act.frame_id, bytes(act.data), send)
    assert node.tick == 0 and node.actuator_ahead == 1
    bad = bytearray(act.data)
    act.pack_raw([1, 2, 0, 5000, 0])
    bad = bytearray(act.data)
    bad[0] ^= 0xFF  # CRC
    node.on_frame(act.frame_id, bytes(bad), send)
    assert node.tick == 0 and node.actuator_rejected == 1
    act.pack_raw([1, 2, 0, 5000, 0])
    node.on_frame(act.frame_id, bytes(act.data), send)
    assert node.tick == 1 and node.duty == pytest.approx(0.5)
    node.on_frame(act.frame_id, bytes(act.data), send)  # the same frame again
    assert node.tick == 1 and node.actuator_rejected == 2  # E2E: repeated counter
    act.pack_raw([1, 2, 0, 9000, 0])  # a fresh frame, but for the tick already run
    node.on_frame(act.frame_id, bytes(act.data), send)
    assert node.tick == 1 and node.actuator_late == 1 and node.duty == pytest.approx(0.5)
    assert sent.count(codec["PlantSensors"].frame_id) == 2


def test_watchdog_removes_pump_power_after_the_configured_ticks():
    node = PlantNode(FastPlant(), watchdog_ticks=3)
    ecu = FakeEcu(node.plant.trim_duty, 10)
    ecu.mute_from = 5
    _run(node, ecu)
    assert node.tick == 5
    for _ in range(3):  # the driver's guard time passes: hold the last command
        node.on_timeout(lambda *_: None)
        assert node.plant.outputs.pump_v > 0.0
        assert not node.plant.outputs.flags & fl.PUMP_UNPOWERED
    node.on_timeout(lambda *_: None)
    assert node.plant.outputs.flags & fl.PUMP_UNPOWERED and node.plant.outputs.pump_v == 0.0
    assert node.watchdog_trips == 1


def test_fault_injection_frame_applies_at_its_tick():
    node = PlantNode(FastPlant())
    ecu = FakeEcu(node.plant.trim_duty, 20)
    ecu.inject[2] = (1, 6, 0.5)  # PUMP_EFFECTIVENESS 0.5 from tick 6
    ecu.inject[3] = (3, 7, 0.9)  # COMPRESSOR_EFFICIENCY: the fast model has none
    ecu.inject[9] = (9, 9, 300.0)  # SPEED_NOISE at once
    effectiveness = []
    node_step = node.plant.step

    def spy(duty, enabled=True, starter_duty=0.0, igniter=False):
        out = node_step(duty, enabled, starter_duty, igniter)
        effectiveness.append(out.pump_effectiveness)
        return out

    node.plant.step = spy
    _run(node, ecu)
    assert effectiveness[5] == 1.0 and effectiveness[6] == 0.5
    assert node.faults_applied == 2 and node.faults_rejected == 1
    assert node.plant.speed_pickup.burst_noise_rpm == 300.0


def test_node_over_a_python_can_bus():
    """run_lockstep drives the node over a real python-can bus (virtual, in-process)."""
    channel = "plant-node-test"
    node = PlantNode(FastPlant(), max_ticks=30)
    plant_bus = can.Bus(interface="virtual", channel=channel)
    ecu_bus = can.Bus(interface="virtual", channel=channel)
    ecu = FakeEcu(node.plant.trim_duty, 1000)
    t = threading.Thread(target=run_lockstep, args=(node, plant_bus), kwargs={"guard_s": 2.0})
    t.start()
    try:
        while t.is_alive():
            msg = ecu_bus.recv(0.5)
            if msg is not None:
                ecu.on_frame(
                    msg.arbitration_id,
                    msg.data,
                    lambda i, d: ecu_bus.send(
                        can.Message(arbitration_id=i, data=bytes(d), is_extended_id=False)
                    ),
                )
        while (msg := ecu_bus.recv(0.2)) is not None:  # the last tick's frames
            ecu.on_frame(msg.arbitration_id, msg.data, lambda *_: None)
    finally:
        t.join(5.0)
        plant_bus.shutdown()
        ecu_bus.shutdown()
    assert node.tick == 30 and node.missed == 0
    assert [s[0] for s in ecu.seen] == list(range(31))


def test_sil_plant_alone_holds_then_loses_pump_power(capsys):
    """No ECU on the bus: every tick runs after the guard time, the watchdog trips."""
    from sil.cli import main

    rc = main(
        [
            "plant",
            "--bus",
            "virtual:sil-plant-alone",
            "--model",
            "fast",
            "--ticks",
            "4",
            "--guard-s",
            "0.01",
            "--watchdog-ticks",
            "2",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "4 ticks" in out and "watchdog trips 1" in out


def test_sil_plant_refuses_a_bad_fault(capsys):
    from sil.cli import main

    with pytest.raises(SystemExit):
        main(["plant", "--fault", "30:pump_effectiveness:2.0"])
    assert "pump_effectiveness value must be in" in capsys.readouterr().err


def test_compiled_frames_are_the_frames_the_codec_packs():
    def frames(codec_path: bool) -> list[tuple[int, bytes]]:
        faults = (Fault(0.3, FaultKind.PUMP_DRY, None, 0.2),)
        node = PlantNode(FastPlant(PlantConfig(seed=2, faults=faults)))
        if codec_path:
            node._state = None  # as for a plant that is not plant.periphery's
        act = Codec()["EcuActuator"]
        sent = []

        def send(frame_id, data):
            sent.append((frame_id, bytes(data)))

        node.start(send)
        for k in range(300):
            duty = 0.0 if 100 < k < 120 else (1.0 if 200 < k < 250 else node.plant.trim_duty)
            act.pack_raw([1 if k % 97 else 0, 2, k, round(duty * 1e4), 0])
            node.on_frame(act.frame_id, bytes(act.data), send)
        return sent

    compiled = frames(False)
    assert len(compiled) == 301 + 3 * 151 + 61 and compiled == frames(True)
