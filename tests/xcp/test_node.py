"""The XCP slave on the ECU node: its frames heard, served at the tick boundary in lockstep (at
once before the first tick), DTOs before the tick's own frames, and the engine frames those of a
node without a master."""

from __future__ import annotations

import struct

from ecu.node import EcuNode
from ecu.params import EcuParams
from ecu.service.port import boot
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import key_for
from ecu.xcp.slave import XcpSlave
from protocol.codec import Codec
from protocol.dbc import xcp_frame_ids

CMD, RES = xcp_frame_ids()


def _node(xcp: bool) -> EcuNode:
    booted = boot(EcuParams(), None)
    node = EcuNode(booted.table.firmware, lockstep=True)
    if xcp:
        node.attach_xcp(XcpSlave(node.ecu, booted, seed=1))
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


def test_the_node_hears_the_xcp_id_and_answers_before_its_first_tick():
    node = _node(True)
    assert CMD in node.frame_ids and (CMD, RES) == (0x700, 0x701)
    sent: list[tuple[int, bytes]] = []
    node.on_frame(CMD, bytes((C.Cmd.CONNECT, 0)), lambda i, d: sent.append((i, bytes(d))))
    assert sent and sent[0][0] == RES and sent[0][1][0] == C.PID_RES
    assert node.timeout_s is not None  # polled while no plant is heard (a store goes on)


def _run(node: EcuNode, master: dict[int, list[bytes]], ticks: int) -> list[tuple[int, bytes]]:
    """Every frame the node sends while a plant ticks it, the master's frames sent before the
    sensor frame of their tick."""
    plant = Plant()
    out: list[tuple[int, bytes]] = []

    def send(frame_id: int, data: bytes | bytearray) -> None:
        out.append((frame_id, bytes(data)))

    for k in range(ticks):
        for frame in master.get(k, []):
            node.on_frame(CMD, frame, send)
        for frame_id, data in plant.frames(k):
            node.on_frame(frame_id, data, send)
    return out


def _daq_setup() -> list[bytes]:
    """A master's DAQ set-up of 20 measurements on the control tick (after CONNECT and the
    DAQ unlock), as frames."""
    frames = [bytes((C.Cmd.FREE_DAQ,)), bytes((C.Cmd.ALLOC_DAQ, 0, 1, 0))]
    entries = [(MEM.measurement_address(k), m.size) for k, m in enumerate(MEM.MEASUREMENTS[:20])]
    odts = [entries[:0]] + [entries[k : k + 1] for k in range(20)]  # ODT 0: the stamp
    frames.append(bytes((C.Cmd.ALLOC_ODT, 0, 0, 0, len(odts))))
    frames += [bytes((C.Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, j, len(o))) for j, o in enumerate(odts)]
    for j, odt in enumerate(odts):
        if odt:
            frames.append(bytes((C.Cmd.SET_DAQ_PTR, 0, 0, 0, j, 0)))
            frames += [struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, n, 0, a) for a, n in odt]
    frames.append(struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 1, 0))
    frames += [bytes((C.Cmd.START_STOP_DAQ_LIST, 2, 0, 0)), bytes((C.Cmd.START_STOP_SYNCH, 1))]
    return frames


def test_engine_frames_with_a_master_attached_are_those_without_one():
    ticks = 300
    plain = _run(_node(False), {}, ticks)
    node = _node(True)
    seed_at = 3
    master: dict[int, list[bytes]] = {1: [bytes((C.Cmd.CONNECT, 0))]}
    master[2] = [bytes((C.Cmd.GET_SEED, 0, C.RES_DAQ))]
    for k, frame in enumerate(_daq_setup(), start=10):
        master[k] = [frame]
    for k in range(100, 250, 2):  # uploads of parameters
        address = MEM.CAL_BASE + 2 * (k - 100)
        master[k] = [struct.pack("<BBBBI", C.Cmd.SHORT_UPLOAD, 4, 0, 0, address)]
    out = _run(node, {k: v for k, v in master.items() if k < seed_at}, seed_at)
    seed = [d for i, d in out if i == RES][-1][2:6]
    master[seed_at] = [bytes((C.Cmd.UNLOCK, 2)) + key_for(seed)]
    node = _node(True)  # the same master again, with the key for its seed (seed 1: the same)
    out = _run(node, master, ticks)
    assert [f for f in out if f[0] != RES] == plain
    xcp = [d for i, d in out if i == RES]
    errors = [d for d in xcp if d[0] == C.PID_ERR]
    assert not errors, errors
    dtos = [d for d in xcp if d[0] < C.PID_SERV]
    assert node.xcp.daq.samples > 200 and len(dtos) == 21 * node.xcp.daq.samples
    # in each tick the XCP frames go before the tick's own frames (EcuActuator closes a tick)
    tick: list[int] = []
    for frame_id, _ in out:
        tick.append(frame_id)
        if frame_id == 0x110:
            xcp_at = [k for k, i in enumerate(tick) if i == RES]
            assert xcp_at == list(range(len(xcp_at))), tick
            tick = []
