"""Two ECUs on one bus: the frames of this ECU's IDs from another sender are another ECU. An ECU
that hears one before it has flown its engine stays silent and says why; one that flies its
engine reports it (its log, its service port's fault log) and goes on flying. In process on
the Python and the C node, and on a bench as an engineer meets it: a plant and an ECU flying the
engine in real time on a loopback bus, then a second ECU (Python, then C) started on it."""

from __future__ import annotations

import math
import time

import can
import pytest

from ecu import modes as M
from ecu.firmware import Ecu
from ecu.node import LISTEN_S, EcuNode
from ecu.params import EcuParams
from ecu.port.core import CEcu
from ecu.port.node import CEcuNode
from protocol.bus import open_bus
from protocol.codec import Codec

CODEC = Codec()
ACTUATOR = CODEC["EcuActuator"]
STATUS = CODEC["EcuStatus"]
SENSORS = CODEC["PlantSensors"]


def python_node(lockstep: bool) -> EcuNode:
    return EcuNode(ecu=Ecu(EcuParams()), lockstep=lockstep)


def c_node(lockstep: bool) -> CEcuNode:
    return CEcuNode(CEcu(EcuParams()), lockstep=lockstep)


NODES = pytest.mark.parametrize("make", [python_node, c_node], ids=("python", "c"))


def _another_ecu_frame(message) -> tuple[int, bytes]:  # noqa: ANN001 (a codec message)
    message.pack_raw([0] * len(message.signal_names))
    return message.frame_id, bytes(message.data)


@NODES
def test_a_real_time_ecu_that_hears_another_before_its_first_tick_stays_silent(make):
    node = make(lockstep=False)
    sent: list[tuple[int, bytes]] = []
    reports: list[str] = []
    node.watch_bus(reports.append)
    listen = math.ceil(LISTEN_S * node.rate_hz)
    for _ in range(listen - 1):
        node.on_period(lambda i, d: sent.append((i, bytes(d))))
    assert sent == [] and not node.finished  # it listens first
    node.on_frame(*_another_ecu_frame(ACTUATOR), lambda i, d: sent.append((i, bytes(d))))
    for _ in range(50):
        node.on_period(lambda i, d: sent.append((i, bytes(d))))
    assert sent == [] and node.finished and node.ticks == 0
    assert len(reports) == 1 and "another ECU is on the bus" in reports[0]
    assert "EcuActuator (0x110)" in reports[0] and "stays silent" in reports[0]


@NODES
def test_two_ecus_coming_up_together_both_stay_silent(make):
    """Another ECU heard in the node's first half second (both came up at once): neither flies
    the engine; sensor frames after it are not answered."""
    node = make(lockstep=True)
    reports: list[str] = []
    node.watch_bus(reports.append)
    sent: list[int] = []
    for k in range(30):
        if k == 10:
            node.on_frame(*_another_ecu_frame(ACTUATOR), lambda i, d: None)
        SENSORS.pack_raw((k, 0, 2_900))
        node.on_frame(SENSORS.frame_id, bytes(SENSORS.data), lambda i, d, k=k: sent.append(k))
    assert node.finished and node.ticks == 10 and max(sent) == 9
    assert len(reports) == 1 and "stays silent" in reports[0]


@NODES
def test_an_ecu_flying_its_engine_reports_another_and_goes_on(make):
    """A lockstep node answering its plant: another ECU's frames are reported (once, and again
    after a quiet second), and the node answers its plant as one that is not watched does."""
    node, alone = make(lockstep=True), make(lockstep=True)
    reports: list[str] = []
    node.watch_bus(reports.append)
    out: list[list[tuple[int, bytes]]] = [[], []]
    for k in range(300):
        if k in (60, 61, 62, 250):  # another ECU: a burst at 0.6 s, again at 2.5 s
            node.on_frame(*_another_ecu_frame(STATUS), lambda i, d: None)
        SENSORS.pack_raw((k, 100_890, 10_480))
        for n, sent in zip((node, alone), out, strict=True):
            n.on_frame(SENSORS.frame_id, bytes(SENSORS.data),
                       lambda i, d, sent=sent: sent.append((i, bytes(d))))  # fmt: skip
    assert out[0] == out[1] and node.ticks == 300 and not node.finished
    assert len(reports) == 2 and all("goes on flying" in r for r in reports)
    assert "EcuStatus (0x200)" in reports[0]
    assert node.watch.summary() == {"other_ecu_frames": 4, "other_ecu_refused": False}


def test_the_service_port_logs_another_ecu():
    """The Python node's service port: another ECU in its fault log, by name."""
    from ecu.service.port import ServicePort, boot
    from ecu.service.transport import open_transport
    from sil.console.client import ServiceClient

    booted = boot(EcuParams(), None)
    node = EcuNode(ecu=Ecu(booted.table.firmware), lockstep=True)
    transport = open_transport("loop://")
    node.service = ServicePort(transport, node.ecu, booted, seed=7)
    node.watch_bus(lambda text: None)

    def tick() -> None:
        SENSORS.pack_raw((node.ticks, 0, 2_900))
        node.on_frame(SENSORS.frame_id, bytes(SENSORS.data), lambda i, d: None)

    client = ServiceClient(transport, timeout_s=5.0, retries=0, idle=tick, first_seq=0)
    for _ in range(60):  # flying for 0.6 s: it reports, and goes on
        tick()
    node.on_frame(*_another_ecu_frame(ACTUATOR), lambda i, d: None)
    assert "OTHER_ECU_ON_BUS" in [e["name"] for e in client.faults()]


@pytest.mark.slow
def test_a_second_ecu_on_a_live_bench_bus_stays_silent(
    tmp_path, sil, sil_process, udp_spec, console, stderr_line
):
    spec = udp_spec()
    plant = sil_process("plant", "--bus", spec, "--realtime", "--standstill", cwd=tmp_path)
    ecu = sil_process("ecu", "--bus", spec, "--mode", "realtime", "--serial", "pty", cwd=tmp_path)
    try:
        port = stderr_line(ecu, "service port: ")
        console.until(port, lambda v: v["inputs_valid"] == 1, 30)
        console(port, "arm")
        assert console.until(port, lambda v: v["mode"] == M.RUN, 90)["mode"] == M.RUN
        console(port, "throttle", "58")
        for impl in ("python", "c", "pil"):  # a second ECU started on the live bus
            second = sil("ecu", "--bus", spec, "--mode", "realtime", "--impl", impl,
                         timeout=60, cwd=tmp_path)  # fmt: skip
            assert second.returncode == 2, second.stderr
            assert "another ECU is on the bus" in second.stderr, second.stderr
            assert "stays silent" in second.stderr
        # another sender of this ECU's status (a device, a test tool): named by the ECU
        with open_bus(spec) as bus:
            frame_id, data = _another_ecu_frame(STATUS)
            bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
        time.sleep(1.0)
        samples = console.live(port, 20)
        faults = [f["name"] for f in console(port, "faults")]
    finally:
        ecu.terminate()
        plant.terminate()
        _, ecu_err = ecu.communicate(timeout=20)
        plant.communicate(timeout=20)
    assert all(s["mode"] == M.RUN for s in samples) and min(s["speed"] for s in samples) > 40
    assert "OTHER_ECU_ON_BUS" in faults and "FLAMEOUT" not in " ".join(faults)
    assert "another ECU is on the bus: EcuStatus (0x200) from another sender" in ecu_err
