"""The C XCP slave on the C CAN node (ecu_node.c, ecu.port.node.CEcuNode) against the Python
slave on the Python node (ecu.node.EcuNode): the same plant and master frames give the same
frames out, in the same order (answers at the tick boundary, before the first sensor frame at
once, DTOs before the tick's own frames); and a lockstep run with a master attached gives the
engine frames of the run without one."""

from __future__ import annotations

import random
import struct

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu.firmware import Ecu
from ecu.node import SERVICE_IDLE_POLL_S, EcuNode
from ecu.params import EcuParams
from ecu.port.core import CEcu
from ecu.port.node import CEcuNode
from ecu.port.xcp import CXcpSlave, XorShiftSeeds, c_limits
from ecu.service.port import boot
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import key_for
from ecu.xcp.slave import XcpSlave
from protocol.codec import Codec
from protocol.dbc import xcp_frame_ids

CMD, RES = xcp_frame_ids()
SEED = 5


def python_node(lockstep: bool = True, xcp: bool = True) -> EcuNode:
    booted = boot(EcuParams(), None)
    node = EcuNode(ecu=Ecu(booted.table.firmware), lockstep=lockstep)
    if xcp:
        slave = XcpSlave(node.ecu, booted, seed=0, limits=c_limits(), clock_us=lambda: 123456)
        slave._rng = XorShiftSeeds(SEED)
        node.attach_xcp(slave)
    return node


def c_node(lockstep: bool = True, xcp: bool = True) -> CEcuNode:
    booted = boot(EcuParams(), None)
    ecu = CEcu(booted.table.firmware)
    node = CEcuNode(ecu, lockstep=lockstep)
    if xcp:
        node.attach_xcp(CXcpSlave(ecu, booted.table, seed=SEED, clock_us=lambda: 123456))
    return node


class Plant:
    """PlantSensors and PlantAnalog frames of an engine at its trim point, tick by tick."""

    def __init__(self) -> None:
        codec = Codec()
        self.sensors, self.analog = codec["PlantSensors"], codec["PlantAnalog"]

    def frames(self, tick: int) -> list[tuple[int, bytes]]:
        out = []
        if tick % 5 == 0:
            self.analog.pack_raw((tick, 22_200, 1_500))
            out.append((self.analog.frame_id, bytes(self.analog.data)))
        self.sensors.pack_raw((tick, 100_890 + (tick * 37) % 200, 10_480))
        out.append((self.sensors.frame_id, bytes(self.sensors.data)))
        return out


def run(node, master: dict[int, list[bytes]], ticks: int, timeouts: bool = False):  # noqa: ANN001, ANN201
    """Every frame the node sends while a plant ticks it; the master's frames of tick k go
    before the sensor frame of k (k < 0: before the plant's first frame)."""
    plant = Plant()
    out: list[tuple[int, bytes]] = []

    def send(frame_id: int, data: bytes | bytearray) -> None:
        out.append((frame_id, bytes(data)))

    for k in range(-3, 0):
        for frame in master.get(k, []):
            node.on_frame(CMD, frame, send)
        if timeouts:
            node.on_timeout(send)
    for k in range(ticks):
        for frame in master.get(k, []):
            node.on_frame(CMD, frame, send)
        for frame_id, data in plant.frames(k):
            node.on_frame(frame_id, data, send)
    return out


def daq_setup(count: int = 20) -> list[bytes]:
    """A master's DAQ set-up of ``count`` measurements on the control tick (after CONNECT and
    the DAQ unlock) packed as pyXCP packs them: entries in ODTs of at most 7 bytes, 3 in the
    first (the timestamp)."""
    entries = [(MEM.measurement_address(k), m.size) for k, m in enumerate(MEM.MEASUREMENTS)]
    entries = entries[:count]
    odts: list[list[tuple[int, int]]] = [[]]
    room = 3
    for address, size in entries:
        if size > room:
            odts.append([])
            room = 7
        odts[-1].append((address, size))
        room -= size
    frames = [bytes((C.Cmd.FREE_DAQ,)), bytes((C.Cmd.ALLOC_DAQ, 0, 1, 0))]
    frames.append(bytes((C.Cmd.ALLOC_ODT, 0, 0, 0, len(odts))))
    frames += [bytes((C.Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, j, len(o))) for j, o in enumerate(odts)]
    for j, odt in enumerate(odts):
        if odt:
            frames.append(bytes((C.Cmd.SET_DAQ_PTR, 0, 0, 0, j, 0)))
            frames += [struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, n, 0, a) for a, n in odt]
    frames.append(struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 1, 0))
    frames += [bytes((C.Cmd.START_STOP_DAQ_LIST, 2, 0, 0)), bytes((C.Cmd.START_STOP_SYNCH, 1))]
    return frames


def _master_with_key(make, ticks: int) -> dict[int, list[bytes]]:  # noqa: ANN001
    """CONNECT and GET_SEED before the plant, the key the seed asks for, 20 measurements by DAQ,
    parameter uploads and a write."""
    master: dict[int, list[bytes]] = {-3: [bytes((C.Cmd.CONNECT, 0))]}
    master[-2] = [bytes((C.Cmd.GET_SEED, 0, C.RES_DAQ))]
    out = run(make(), master, 0)
    seed = [d for i, d in out if i == RES][-1][2:6]
    master[-1] = [bytes((C.Cmd.UNLOCK, 2)) + key_for(seed)]
    for k, frame in enumerate(daq_setup(), start=10):
        master[k] = [frame]
    for k in range(60, ticks - 20, 3):
        address = MEM.CAL_BASE + 4 * ((k * 7) % 117)
        master[k] = [struct.pack("<BBBBI", C.Cmd.SHORT_UPLOAD, 4, 0, 0, address)]
    return master


def test_the_c_node_sends_what_the_python_node_sends_with_a_master():
    ticks = 250
    master = _master_with_key(python_node, ticks)
    py = run(python_node(), master, ticks, timeouts=True)
    c = run(c_node(), master, ticks, timeouts=True)
    assert c == py
    dtos = [d for i, d in c if i == RES and d[0] < C.PID_SERV]
    assert len(dtos) > 200 * 6 and not [d for i, d in c if i == RES and d[0] == C.PID_ERR]


def test_engine_frames_with_a_master_attached_are_those_without_one():
    ticks = 300
    plain = run(c_node(xcp=False), {}, ticks)
    out = run(c_node(), _master_with_key(c_node, ticks), ticks)
    assert [f for f in out if f[0] != RES] == plain
    # in each tick the XCP frames go before the tick's own frames (EcuActuator closes a tick)
    tick: list[int] = []
    for frame_id, _ in out:
        tick.append(frame_id)
        if frame_id == 0x110:
            xcp_at = [k for k, i in enumerate(tick) if i == RES]
            assert xcp_at == list(range(len(xcp_at))), tick
            tick = []


def test_before_the_plant_the_c_node_answers_at_once_and_polls():
    node = c_node()
    assert CMD in node.frame_ids and node.timeout_s == SERVICE_IDLE_POLL_S
    sent: list[tuple[int, bytes]] = []
    node.on_frame(CMD, bytes((C.Cmd.CONNECT, 0)), lambda i, d: sent.append((i, bytes(d))))
    assert sent == [(RES, bytes((0xFF, 0x05, 0x80, 8, 8, 0, 1, 1)))]
    node.on_frame(CMD, bytes((C.Cmd.GET_STATUS,)), lambda i, d: sent.append((i, bytes(d))))
    assert sent[-1] == (RES, bytes((0xFF, 0, 0x05, 0, 0, 0)))  # (a 1-byte frame is heard)
    assert c_node(xcp=False).timeout_s is None


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.tuples(st.integers(-3, 40), st.binary(min_size=1, max_size=8)), max_size=40),
    st.booleans(),
)
def test_random_master_frames_on_both_nodes_send_the_same(frames, lockstep):
    """Any master frames at any tick, lockstep or real time (on_period): the same frames out."""
    master: dict[int, list[bytes]] = {-3: [bytes((C.Cmd.CONNECT, 0))]}
    for tick, frame in frames:
        master.setdefault(tick, []).append(frame)
    if lockstep:
        assert run(c_node(), master, 45, timeouts=True) == run(
            python_node(), master, 45, timeouts=True
        )
        return
    out = []
    for node in (python_node(lockstep=False), c_node(lockstep=False)):
        sent: list[tuple[int, bytes]] = []

        def send(i: int, d: bytes, sent: list = sent) -> None:
            sent.append((i, bytes(d)))

        for k in range(-3, 45):
            for frame in master.get(k, []):
                node.on_frame(CMD, frame, send)
            if k >= 0:
                node.on_period(send)
        out.append(sent)
    assert out[0] == out[1]


def test_a_bench_start_over_xcp_on_both_nodes():
    """The bench's arm and throttle over XCP on a node whose plant is at rest: the same frames
    (the start's EcuStarter frames among them)."""
    rng = random.Random(2)
    codec = Codec()
    sensors = codec["PlantSensors"]
    outs = []
    for make in (python_node, c_node):
        node = make()
        sent: list[tuple[int, bytes]] = []

        def send(i: int, d: bytes, sent: list = sent) -> None:
            sent.append((i, bytes(d)))

        node.on_frame(CMD, bytes((C.Cmd.CONNECT, 0)), send)
        node.on_frame(CMD, bytes((C.Cmd.GET_SEED, 0, C.RES_CAL_PAG)), send)
        seed = sent[-1][1][2:6]
        node.on_frame(CMD, bytes((C.Cmd.UNLOCK, 2)) + key_for(seed), send)
        for k in range(400):
            if k in (5, 200):
                node.on_frame(CMD, struct.pack("<BBBBI", C.Cmd.SET_MTA, 0, 0, 0, MEM.BENCH_BASE),
                              send)  # fmt: skip
                node.on_frame(CMD, bytes((C.Cmd.DOWNLOAD, 4)) + struct.pack("<i", 1), send)
            if k == 300:
                node.on_frame(CMD, struct.pack("<BBBBI", C.Cmd.SET_MTA, 0, 0, 0,
                                               MEM.BENCH_BASE + 8), send)  # fmt: skip
                node.on_frame(CMD, bytes((C.Cmd.DOWNLOAD, 4)) + struct.pack("<i", 6000), send)
            sensors.pack_raw((k, min(k * 100, 20_000) + rng.randrange(0, 3), 2_900 + 5 * k))
            node.on_frame(sensors.frame_id, bytes(sensors.data), send)
        outs.append(sent)
        rng.seed(2)
    assert outs[0] == outs[1]
    assert any(i == codec["EcuStarter"].frame_id for i, _ in outs[1])
