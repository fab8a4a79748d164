"""The C frame code (cantools-generated pack/unpack plus E2E) against the Python codec, E2E
checker and ECU node: the same bytes out, the same verdicts and values in."""

import ctypes
import random

import pytest

from ecu.firmware import E2E_OK
from ecu.node import EcuNode
from ecu.port import core
from protocol.codec import Codec


class Frames(ctypes.Structure):
    _fields_ = [
        ("rx_last", ctypes.c_int8 * 3),
        ("tx_counter", ctypes.c_uint8 * 3),
        ("telemetry_index", ctypes.c_uint8),
    ]


@pytest.fixture(scope="module")
def lib():
    lib = core.library().lib
    lib.ecu_frames_init.argtypes = [ctypes.c_void_p]
    lib.ecu_frames_receive.argtypes = [
        ctypes.c_void_p, ctypes.c_uint32, ctypes.c_char_p, ctypes.c_void_p, ctypes.c_void_p
    ]  # fmt: skip
    lib.ecu_frames_receive.restype = ctypes.c_int
    for name in ("ecu_frames_actuator", "ecu_frames_status", "ecu_frames_telemetry"):
        getattr(lib, name).argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    return lib


def test_received_frames_get_the_python_verdicts_and_values(lib):
    codec = Codec()
    rng = random.Random(5)
    frames = Frames()
    lib.ecu_frames_init(ctypes.byref(frames))
    inputs = core.library().inputs_t()
    demand_tick = ctypes.c_int32(-1)
    msgs = {m: codec[m] for m in ("PlantSensors", "PlantAnalog", "Demand")}
    checkers = {m: c.checker(max_delta=2) for m, c in msgs.items()}
    fields = {
        "PlantSensors": ("tick", "speed_rpm", "egt_dk"),
        "PlantAnalog": (None, "supply_mv", "pump_ma"),
        "Demand": ("arm", "stop", "demand_cpct", "open_loop_mv", None),
    }
    verdicts = set()
    for _ in range(3000):
        name = rng.choice(list(msgs))
        m = msgs[name]
        raws = [rng.randint(s.raw_min, s.raw_max) for s in m.signals]
        m.pack_raw(raws)
        data = bytearray(m.data)
        roll = rng.random()
        if roll < 0.05:
            data[rng.randrange(8)] ^= 1 << rng.randrange(8)  # corrupted
        elif roll < 0.10:
            m.pack_raw(raws)  # the previous frame is lost: counter skips one
            data = bytearray(m.data)
        elif roll < 0.13:
            m.counter = (m.counter + 5) % 15  # a gap the checker refuses
        expected = checkers[name].check(bytes(data))
        got = lib.ecu_frames_receive(
            ctypes.byref(frames), m.frame_id, bytes(data), ctypes.byref(inputs),
            ctypes.byref(demand_tick),
        )  # fmt: skip
        assert got == expected, name
        verdicts.add(got)
        if got == E2E_OK:
            out = [0] * len(m.signal_names)
            m.unpack_raw(data, out)
            for value, field in zip(out, fields[name], strict=True):
                if field is not None:
                    assert getattr(inputs, field) == value, f"{name}.{field}"
            if name == "Demand":
                assert demand_tick.value == out[4]
        if roll >= 0.13 and rng.random() < 0.03:  # the same frame again: REPEATED
            again = checkers[name].check(bytes(data))
            assert again == lib.ecu_frames_receive(
                ctypes.byref(frames), m.frame_id, bytes(data), ctypes.byref(inputs),
                ctypes.byref(demand_tick),
            )  # fmt: skip
            verdicts.add(again)
    assert verdicts == {0, 1, 2, 3}
    assert lib.ecu_frames_receive(
        ctypes.byref(frames), 0x210, bytes(8), ctypes.byref(inputs), ctypes.byref(demand_tick)
    ) == -1  # fmt: skip


def test_sent_frames_are_byte_identical_to_the_python_node(lib):
    node = EcuNode(ecu=core.CEcu(), lockstep=False)
    sent: list[tuple[int, bytes]] = []
    frames = Frames()
    lib.ecu_frames_init(ctypes.byref(frames))
    data = (ctypes.c_uint8 * 8)()
    rng = random.Random(3)
    i = node.i
    expected: list[tuple[int, bytes]] = []
    for k in range(1500):
        i.speed_rpm = 100900 + rng.randint(-3000, 3000)
        i.egt_dk, i.supply_mv, i.pump_ma = 10480 + rng.randint(-200, 3000), 22200, 1700
        i.demand_cpct, i.arm, i.stop = rng.choice((8968, 9300, 8500)), 1, 0
        i.sensor_status = i.analog_status = i.demand_status = E2E_OK
        node.on_period(lambda fid, d: sent.append((fid, bytes(d))))
        e = ctypes.byref(node.ecu._ecu)
        out = ctypes.byref(node.ecu.out)
        if k % node.every_status == 0:
            lib.ecu_frames_status(ctypes.byref(frames), out, data)
            expected.append((0x200, bytes(data)))
        if k % node.every_telemetry == 0:
            lib.ecu_frames_telemetry(ctypes.byref(frames), e, data)
            expected.append((0x210, bytes(data)))
        lib.ecu_frames_actuator(ctypes.byref(frames), out, data)
        expected.append((0x110, bytes(data)))
    assert len(sent) == len(expected)
    for n, (a, b) in enumerate(zip(sent, expected, strict=True)):
        assert a == b, f"frame {n}: python {a[0]:#x} {a[1].hex()}, c {b[0]:#x} {b[1].hex()}"
    assert {node.ecu.out.mode} == {2} and node.ecu.out.sat_events >= 0
