"""A start from the bench over XCP always goes to idle, on the Python and the C ECU: the bench's
throttle belongs to the run it was set in. On both nodes in process (the same frames out, the
bench_throttle read back at idle once the run ended), and on a bench as the page meets it: a
real-time plant and the C ECU as processes on a loopback bus, pyXCP arming, throttling,
stopping and arming again."""

from __future__ import annotations

import struct
import time

import pytest

from ecu import modes as M
from ecu.firmware_params import compile_params
from ecu.params import EcuParams
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import key_for
from protocol.codec import Codec
from protocol.dbc import xcp_frame_ids
from tests.xcp.test_c_node import c_node, python_node

CMD, RES = xcp_frame_ids()
IDLE_CPCT = round(100 * compile_params(EcuParams()).idle_q24 / (1 << 24))


def _write(index: int, value: int) -> list[bytes]:
    address = MEM.bench_address(index)
    return [
        struct.pack("<BBBBI", C.Cmd.SET_MTA, 0, 0, 0, address),
        bytes((C.Cmd.DOWNLOAD, 4)) + struct.pack("<i", value),
    ]


def _read_throttle() -> bytes:
    address = MEM.bench_address(MEM.BENCH_THROTTLE)
    return struct.pack("<BBBBI", C.Cmd.SHORT_UPLOAD, 4, 0, 0, address)


def _bench_session(make) -> tuple[list[tuple[int, bytes]], list[int], list[int]]:  # noqa: ANN001
    """A node at rest (the rotor still, the EGT cold), a master that arms, throttles to 73 %N,
    stops in the spin-up, throttles to 64 %N at rest and arms again: every frame out, the
    bench_throttle read back after each step, and the mode after each tick."""
    node = make()
    codec = Codec()
    sensors, analog = codec["PlantSensors"], codec["PlantAnalog"]
    out: list[tuple[int, bytes]] = []

    def send(frame_id: int, data: bytes | bytearray) -> None:
        out.append((frame_id, bytes(data)))

    node.on_frame(CMD, bytes((C.Cmd.CONNECT, 0)), send)
    node.on_frame(CMD, bytes((C.Cmd.GET_SEED, 0, C.RES_CAL_PAG)), send)
    node.on_frame(CMD, bytes((C.Cmd.UNLOCK, 2)) + key_for(out[-1][1][2:6]), send)
    master = {
        5: _write(MEM.BENCH_ARM, 1),
        8: _write(MEM.BENCH_THROTTLE, 7_300) + [_read_throttle()],
        12: _write(MEM.BENCH_STOP, 1),
        20: [_read_throttle()] + _write(MEM.BENCH_THROTTLE, 6_400),
        22: _write(MEM.BENCH_ARM, 1) + [_read_throttle()],
    }
    modes = []
    for k in range(40):
        for frame in master.get(k, []):
            node.on_frame(CMD, frame, send)
        if k % 5 == 0:
            analog.pack_raw((k, 22_200, 0))
            node.on_frame(analog.frame_id, bytes(analog.data), send)
        sensors.pack_raw((k, 0, 2_900))
        node.on_frame(sensors.frame_id, bytes(sensors.data), send)
        modes.append(node.ecu.out.mode)
    reads = [d for i, d in out if i == RES and len(d) == 5 and d[0] == C.PID_RES]
    return out, [struct.unpack("<i", d[1:5])[0] for d in reads[-3:]], modes


def test_a_restart_over_xcp_goes_to_idle_on_both_nodes():
    py_out, py_reads, modes = _bench_session(python_node)
    c_out, c_reads, _ = _bench_session(c_node)
    assert c_out == py_out
    assert py_reads == c_reads == [7_300, IDLE_CPCT, IDLE_CPCT]
    assert modes[10] == M.ARMED and modes[18] == M.OFF and modes[-1] == M.ARMED


@pytest.mark.slow
def test_pyxcp_restart_of_the_c_ecu_goes_to_idle(tmp_path, udp_group, xcp_tools, sil_process):
    group, port = udp_group
    udp = f"udp:{group}@{port}"
    plant = sil_process("plant", "--bus", udp, "--realtime", "--standstill")
    ecu = sil_process("ecu", "--bus", udp, "--impl", "c", "--mode", "realtime",
                      "--flash", str(tmp_path / "flash.bin"))  # fmt: skip
    try:
        _wait_line(ecu, "xcp: ")
        with xcp_tools.master("turbojet_udp", group, port=port) as x:
            x.connect()
            x.cond_unlock("calpag")
            _until(x, "inputs_valid", lambda v: v == 1, 30)
            _bench(x, MEM.BENCH_ARM, 1)
            _until(x, "mode", lambda v: v == M.ARMED, 10)
            _bench(x, MEM.BENCH_THROTTLE, 8_600)
            _bench(x, MEM.BENCH_STOP, 1)
            assert _until(x, "mode", lambda v: v == M.OFF, 30) == M.OFF
            _bench(x, MEM.BENCH_ARM, 1)
            assert _until(x, "mode", lambda v: v == M.RUN, 90) == M.RUN
            time.sleep(4.0)  # the old throttle would take it past 60 %N by now
            demand = _physical("demand", _measure(x, "demand"))
            speed = _physical("speed", _measure(x, "speed"))
            x.setMta(MEM.bench_address(MEM.BENCH_THROTTLE))
            throttle = struct.unpack("<i", x.fetch(4))[0]
            mode = _measure(x, "mode")
            x.disconnect()
    finally:
        for proc in (ecu, plant):
            proc.terminate()
        for proc in (ecu, plant):
            proc.communicate(timeout=20)
    assert mode == M.RUN and throttle == IDLE_CPCT
    assert demand == pytest.approx(IDLE_CPCT / 100, abs=0.01) and speed < IDLE_CPCT / 100 + 5


def _wait_line(proc, prefix: str, limit_s: float = 90) -> None:  # noqa: ANN001
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        assert line, f"sil ecu exited with {proc.poll()}"
        if line.startswith(prefix):
            return
    raise AssertionError(f"no {prefix!r} line")


def _bench(x, index: int, value: int) -> None:  # noqa: ANN001 (a pyXCP Master)
    x.setMta(MEM.bench_address(index))
    x.download(struct.pack("<i", value))


def _measure(x, name: str) -> int:  # noqa: ANN001
    k = MEM.MEAS_INDEX[name]
    m = MEM.MEASUREMENTS[k]
    code = MEM.TYPES[m.datatype][0]
    return struct.unpack("<" + code, x.shortUpload(m.size, MEM.measurement_address(k)))[0]


def _physical(name: str, raw: int) -> float:
    m = MEM.MEASUREMENTS[MEM.MEAS_INDEX[name]]
    return raw * m.factor


def _until(x, name: str, done, limit_s: float) -> int:  # noqa: ANN001
    """The measurement ``name`` polled until ``done(value)`` or ``limit_s``; its last value."""
    deadline = time.monotonic() + limit_s
    while not done(value := _measure(x, name)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return value
