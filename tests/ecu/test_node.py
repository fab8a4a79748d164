"""The ECU as a CAN node: lockstep with a plant and a command node, in process and over a bus."""

from __future__ import annotations

import json
import threading

import can
import pytest

from ecu import faults as F
from ecu.modes import RUN
from ecu.node import EcuNode
from ecu.params import EcuParams
from plant.fast_model import FastEngine
from protocol.codec import Codec
from protocol.node import InProcessBus
from sil.cli import main

STEP_TICK = 300


class FakePlant:
    """Eq. 3.24 plant following the lockstep rules: sensors(k), wait for actuator(k), step."""

    def __init__(self, codec: Codec, ticks: int, ecu_node: EcuNode, corrupt_tick: int = -1):
        self.sensors, self.analog = codec["PlantSensors"], codec["PlantAnalog"]
        self.actuator = codec["EcuActuator"]
        self.check = self.actuator.checker()
        self.plant = FastEngine()
        self.ticks, self.ecu_node, self.corrupt_tick = ticks, ecu_node, corrupt_tick
        self.k = 0
        self.raw = [0] * 5
        self.mismatches = 0
        self.demand_q24: list[int] = []
        self.faults: list[int] = []
        self.finished = False

    def _send_tick(self, send) -> None:  # noqa: ANN001
        k = self.k
        if k % 5 == 0:
            self.analog.pack_raw([k, 22200, 1800])
            send(self.analog.frame_id, self.analog.data)
        self.sensors.pack_raw([k, round(self.plant.n_pct * 1125), 10480])
        data = bytearray(self.sensors.data)
        if k == self.corrupt_tick:
            data[5] ^= 0x40  # a flipped bit: WRONGCRC at the ECU
        send(self.sensors.frame_id, data)

    def start(self, send) -> None:  # noqa: ANN001
        self._send_tick(send)

    def on_frame(self, frame_id: int, data, send) -> None:  # noqa: ANN001
        if frame_id != self.actuator.frame_id:
            return
        assert self.check.check(data) == 0
        self.actuator.unpack_raw(data, self.raw)
        enable, _, tick, _, mv = self.raw
        self.mismatches += tick != self.k
        out = self.ecu_node.ecu.out
        self.demand_q24.append(self.ecu_node.ecu.s.demand_q24)
        self.faults.append(out.fault_word)
        self.plant.step(mv / 1000.0 - EcuParams().trim_v if enable else 0.0, 0.01)
        self.k += 1
        if self.k >= self.ticks:
            self.finished = True
        else:
            self._send_tick(send)

    def on_timeout(self, send) -> None:  # noqa: ANN001
        pass

    def on_period(self, send) -> None:  # noqa: ANN001
        pass


class FakeCommand:
    """Sends the Demand for tick k + 5 on PlantSensors(k), as protocol.lockstep prescribes."""

    def __init__(self, codec: Codec) -> None:
        self.demand = codec["Demand"]
        self.finished = False

    def _send(self, tick: int, send) -> None:  # noqa: ANN001
        cpct = 9200 if tick >= STEP_TICK else 8968
        self.demand.pack_raw([1, 0, cpct, 0, tick])
        send(self.demand.frame_id, self.demand.data)

    def start(self, send) -> None:  # noqa: ANN001
        self._send(0, send)

    def on_frame(self, frame_id: int, data, send) -> None:  # noqa: ANN001
        if frame_id == 0x100:
            k = int.from_bytes(bytes(data[2:4]), "little")
            if (k + 5) % 5 == 0:
                self._send(k + 5, send)

    def on_timeout(self, send) -> None:  # noqa: ANN001
        pass

    def on_period(self, send) -> None:  # noqa: ANN001
        pass


@pytest.fixture(scope="module")
def lockstep_run() -> tuple[FakePlant, EcuNode, list[tuple[int, bytes]]]:
    codec = Codec()
    node = EcuNode(codec=codec)
    plant = FakePlant(codec, 1500, node, corrupt_tick=1000)
    frames: list[tuple[int, bytes]] = []
    bus = InProcessBus([plant, FakeCommand(codec), node], tap=lambda f, d: frames.append((f, d)))
    bus.run(done=lambda: plant.finished)
    return plant, node, frames


def test_lockstep_answers_every_tick_and_controls_the_plant(lockstep_run) -> None:  # noqa: ANN001
    plant, node, _ = lockstep_run
    assert plant.k == 1500 and plant.mismatches == 0 and node.ticks == 1500
    assert node.ecu.out.mode == RUN and node.demand_waits == 0
    assert abs(plant.plant.n_pct - 92.0) < 0.05


def test_demand_applies_at_its_tick_not_when_it_arrives(lockstep_run) -> None:  # noqa: ANN001
    plant, _, _ = lockstep_run
    q24 = 1 << 24  # the step's Demand arrived 5 ticks before its tick
    assert plant.demand_q24[STEP_TICK - 1] == 8968 * q24 // 100
    assert plant.demand_q24[STEP_TICK] == 92 * q24


def test_a_corrupted_sensor_frame_is_substituted_and_answered(lockstep_run) -> None:  # noqa: ANN001
    plant, node, _ = lockstep_run
    assert plant.faults[1000] & F.SENSOR_FRAME_LOST
    assert not plant.faults[1001] & F.SENSOR_FRAME_LOST
    assert node.sensors_check.counts[3] == 1  # one WRONGCRC


def test_status_and_telemetry_frames_decode_with_cantools(lockstep_run) -> None:  # noqa: ANN001
    _, _, frames = lockstep_run
    db = Codec().database
    status = [db.decode_message(f, d) for f, d in frames if f == 0x200]
    assert len(status) == 1500 // 5 and str(status[-1]["EcuMode"]) == "RUN"
    assert abs(status[-1]["ReferenceSpeed"] - 92.0) < 0.02
    lam = [db.decode_message(f, d) for f, d in frames if f == 0x210 and d[2] == 2]
    assert lam and abs(lam[-1]["Est_Lambda"] - 4.822) < 0.05
    sat = [db.decode_message(f, d) for f, d in frames if f == 0x210 and d[2] == 12]
    assert sat[-1]["SaturationCount"] == 0


def test_sil_ecu_over_a_python_can_bus(capsys: pytest.CaptureFixture[str]) -> None:
    channel = "virtual:sil_ecu_cli_test"
    codec = Codec()
    sensors, analog, demand = codec["PlantSensors"], codec["PlantAnalog"], codec["Demand"]
    actuator = codec["EcuActuator"]
    plant_bus = can.Bus(interface="virtual", channel=channel.split(":")[1])
    result: dict = {}
    t = threading.Thread(
        target=lambda: result.setdefault(
            "code", main(["ecu", "--bus", channel, "--ticks", "40", "--json"])
        )
    )
    t.start()
    try:
        raw = [0] * 5
        answered = 0
        for k in range(40):
            if k % 5 == 0:
                demand.pack_raw([1, 0, 8968, 0, k])
                plant_bus.send(
                    can.Message(
                        arbitration_id=demand.frame_id, data=demand.data, is_extended_id=False
                    )
                )
                analog.pack_raw([k, 22200, 1800])
                plant_bus.send(
                    can.Message(
                        arbitration_id=analog.frame_id, data=analog.data, is_extended_id=False
                    )
                )
            sensors.pack_raw([k, 100890, 10300])
            msg = can.Message(
                arbitration_id=sensors.frame_id, data=sensors.data, is_extended_id=False
            )
            for _ in range(50):  # the ECU may not be listening yet: resend until answered
                plant_bus.send(msg)
                reply = plant_bus.recv(0.2)
                while reply is not None and reply.arbitration_id != actuator.frame_id:
                    reply = plant_bus.recv(0.2)
                if reply is not None:
                    break
            assert reply is not None
            actuator.unpack_raw(reply.data, raw)
            answered += raw[2] == k
        t.join(10)
    finally:
        plant_bus.shutdown()
    assert not t.is_alive() and result["code"] == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["ticks"] == 40 and summary["mode"] == RUN and answered == 40


def test_real_time_node_ticks_on_its_own_clock() -> None:
    codec = Codec()
    node = EcuNode(codec=codec, lockstep=False, max_ticks=20)
    sensors, analog, demand = codec["PlantSensors"], codec["PlantAnalog"], codec["Demand"]
    actuator = codec["EcuActuator"]
    sent: list[tuple[int, bytes]] = []

    def send(frame_id: int, data) -> None:  # noqa: ANN001
        sent.append((frame_id, bytes(data)))

    node.start(send)
    raw = [0] * 5
    for k in range(20):
        if k % 5 == 0:
            demand.pack_raw([1, 0, 8968, 0, 0])  # DemandTick is not used in real time
            node.on_frame(demand.frame_id, demand.data, send)
            analog.pack_raw([0, 22200, 1800])
            node.on_frame(analog.frame_id, analog.data, send)
        if k != 10:  # one period without a sensor frame: substituted, flagged
            sensors.pack_raw([0, 100890, 10480])
            node.on_frame(sensors.frame_id, sensors.data, send)
        node.on_period(send)
        actuator.unpack_raw(sent[-1][1], raw)
        assert sent[-1][0] == actuator.frame_id and raw[2] == k  # own tick counter
        if k == 10:
            assert node.ecu.out.fault_word & F.SENSOR_FRAME_LOST
    assert node.finished and node.ecu.out.mode == RUN and raw[0] == 1


def _late_ecu_feed(node: EcuNode, codec: Codec, script: list[tuple[str, int]]) -> dict[int, int]:
    """Feed Demand ("D", tick) and PlantSensors ("S", tick) frames in the script's order; the
    firmware's speed demand (%N x 100) after each tick it ran."""
    demand, sensors = codec["Demand"], codec["PlantSensors"]
    seen: dict[int, int] = {}
    for kind, tick in script:
        if kind == "D":
            demand.pack_raw([1, 0, 8000 + tick, 0, tick])  # a speed that names its tick
            node.on_frame(demand.frame_id, demand.data, lambda f, d: None)
        else:
            sensors.pack_raw([tick, 100_000, 10_480])
            node.on_frame(sensors.frame_id, sensors.data, lambda f, d: None)
            seen[tick] = round(node.ecu.s.demand_q24 * 100 / (1 << 24))
    return seen


def test_a_demand_arriving_before_the_late_tick_it_follows_does_not_overwrite_it() -> None:
    """While sensor frames are lost the ECU ticks late, on its own clock, and the Demand for
    tick k + 5 can arrive before tick k has run: both are held, each applies at its tick, and
    the demand never goes stale (no DEMAND_LOST)."""
    codec = Codec()
    node = EcuNode(codec=codec)
    script = [("D", 0), ("S", 0), ("D", 5)] + [("S", k) for k in range(1, 4)]
    script += [("D", 10), ("S", 4), ("S", 5), ("D", 15)] + [("S", k) for k in range(6, 10)]
    script += [("D", 20), ("S", 10), ("S", 11)]
    seen = _late_ecu_feed(node, codec, script)
    assert [seen[k] for k in (0, 4, 5, 9, 10, 11)] == [8000, 8000, 8005, 8005, 8010, 8010]
    assert node.demand_pending == 1 and node.demand_waits == 0
    assert not node.ecu.out.fault_word & F.DEMAND_LOST


def test_when_two_held_demands_are_both_due_the_later_one_applies() -> None:
    codec = Codec()
    node = EcuNode(codec=codec)
    seen = _late_ecu_feed(node, codec, [("D", 0), ("S", 0), ("D", 5), ("D", 10), ("S", 10)])
    assert seen == {0: 8000, 10: 8010} and node.demand_pending == 0


def test_a_third_held_demand_replaces_the_later_of_the_two() -> None:
    codec = Codec()
    node = EcuNode(codec=codec)
    script = [("D", 0), ("S", 0), ("D", 5), ("D", 10), ("D", 15), ("S", 5)]
    seen = _late_ecu_feed(node, codec, script)
    assert seen == {0: 8000, 5: 8005}
    assert node.demand_pending == 1 and node.demand_tick == 15


def test_a_late_sensor_frame_is_data_for_the_next_tick_not_a_tick_again() -> None:
    """The ECU ran tick 2 on its own clock (the frame was late); when PlantSensors(2) comes it
    does not run tick 2 again (nor a repeated frame), its values go to tick 3."""
    codec = Codec()
    node = EcuNode(codec=codec)
    sensors = codec["PlantSensors"]
    sent: list[int] = []

    def send(frame_id: int, data) -> None:  # noqa: ANN001
        sent.append(frame_id)

    for k in (0, 1):
        sensors.pack_raw([k, 100_000, 10_480])
        node.on_frame(sensors.frame_id, sensors.data, send)
    node.on_timeout(send)  # tick 2 without its sensor frame
    assert (node.ticks, node.tick, node.ecu.s.sensor_age) == (3, 2, 1)
    sensors.pack_raw([2, 101_000, 10_480])
    node.on_frame(sensors.frame_id, sensors.data, send)
    node.on_frame(sensors.frame_id, sensors.data, send)  # the same frame again: repeated
    assert (node.ticks, node.late_sensor_frames) == (3, 2)
    node.on_timeout(send)  # tick 3 takes the late frame's values as fresh
    assert (node.ticks, node.tick, node.ecu.s.sensor_age) == (4, 3, 0)
    assert sent.count(codec["EcuActuator"].frame_id) == 4
