"""Bench test functions (ecu/actuator_tests.py): the firmware runs each for its time and stops,
in the Python tick and the C core alike (every output and the state digest, every tick); it
refuses them outside OFF; XCP's bench words ask for them and refuse them outside OFF, with a
fault latched or an arm present (ERR_ACCESS_DENIED), beyond their limits (ERR_OUT_OF_RANGE)
and locked (ERR_ACCESS_LOCKED), the same in the Python and the C slave; a stop or an arm ends
one; the plant sees the outputs (a starter spin turns the shaft)."""

from __future__ import annotations

import struct

import pytest

from ecu import actuator_tests as T
from ecu import golden
from ecu import modes as M
from ecu.firmware import E2E_NONEWDATA, E2E_OK, Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.port.core import CEcu
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import key_for
from tests.xcp.test_c_slave import Rigs

P = EcuParams()
RATE = P.rate_hz


def _at_rest(i: EcuInputs, k: int) -> EcuInputs:
    i.sensor_status = i.analog_status = E2E_OK
    i.demand_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
    i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma, i.demand_cpct = 0, 2900, 22200, 0, 3500
    return i


# (first tick, request, level, ms, arm, stop): held from that tick on
SCRIPT = (
    (10, T.GLOW, 0, 300, 0, 0),  # 30 ticks of the igniter
    (60, T.NONE, 0, 0, 0, 0),
    (70, T.STARTER, 2500, 500, 0, 0),  # 50 ticks at 25 %
    (140, T.NONE, 0, 0, 0, 0),
    (150, T.PRIME, 2000, 200, 0, 0),  # 20 ticks at 2 V
    (190, T.NONE, 0, 0, 0, 0),
    (200, T.STARTER, 99999, 500, 0, 0),  # beyond the starter's duty: not started
    (210, T.NONE, 0, 0, 0, 0),
    (220, T.GLOW, 0, 20000, 0, 0),  # beyond 10 s: not started
    (230, T.STARTER, 2500, 1000, 0, 0),  # ended by the request dropped at 260
    (260, T.NONE, 0, 0, 0, 0),
    (270, T.GLOW, 0, 1000, 0, 0),  # ended by a stop request at 290
    (290, T.GLOW, 0, 1000, 0, 1),
    (300, T.NONE, 0, 0, 0, 0),
    (310, T.PRIME, 1500, 1000, 0, 0),  # ended by an arm at 330 (ARMED: a start)
    (330, T.PRIME, 1500, 1000, 1, 0),
    (360, T.STARTER, 2500, 1000, 1, 0),  # a new request in ARMED: refused
    (400, T.STARTER, 2500, 1000, 1, 0),
)


def _script_inputs(ticks: int = 420):
    i = EcuInputs()
    row = (T.NONE, 0, 0, 0, 0)
    steps = dict((k, rest) for k, *rest in ((s[0], *s[1:]) for s in SCRIPT))
    for k in range(ticks):
        row = tuple(steps.get(k, row))
        i.test_request, i.test_level, i.test_ms, i.arm, i.stop = row
        yield k, _at_rest(i, k)


def _run_both():
    py, c = Ecu(P), CEcu(P)
    rows = []
    for k, i in _script_inputs():
        a, b = py.tick(i), c.tick(i)
        for name in golden.OUTPUT_FIELDS:
            assert getattr(a, name) == getattr(b, name), f"tick {k}: {name}"
        assert golden.state_digest(py.s) == c.digest(), f"tick {k}"
        rows.append((k, a.mode, a.igniter, a.starter_cpct, a.pump_enable, a.pump_mv, a.duty_cpct,
                     py.s.test_active, py.s.test_time_left_ms))  # fmt: skip
    return rows


@pytest.fixture(scope="module")
def rows():
    return _run_both()


def _ticks(rows, lo: int, hi: int, column: int) -> list[int]:
    return [r[0] for r in rows if lo <= r[0] < hi and r[column]]


def test_each_test_runs_its_time_and_stops_in_python_and_c(rows):
    assert _ticks(rows, 0, 60, 2) == list(range(10, 10 + 300 * RATE // 1000))  # igniter
    assert _ticks(rows, 60, 140, 3) == list(range(70, 70 + 500 * RATE // 1000))  # starter
    assert {r[3] for r in rows if 70 <= r[0] < 120} == {2500}
    assert _ticks(rows, 140, 190, 4) == list(range(150, 150 + 200 * RATE // 1000))  # pump
    assert {r[5] for r in rows if 150 <= r[0] < 170} == {2000}
    assert {r[6] for r in rows if 150 <= r[0] < 170} == {2000 * 10000 // 22200}
    # the time left counts down in ms; none once over
    assert [r[8] for r in rows if r[0] in (10, 11, 39, 40)] == [290, 280, 0, 0]
    assert all(r[1] == M.OFF for r in rows if r[0] < 330)


def test_out_of_range_requests_do_not_start(rows):
    assert not _ticks(rows, 200, 230, 3) and not _ticks(rows, 200, 230, 2)


def test_dropping_the_request_a_stop_or_an_arm_ends_a_test(rows):
    assert _ticks(rows, 230, 270, 3) == list(range(230, 260))
    assert _ticks(rows, 270, 310, 2) == list(range(270, 290))
    assert _ticks(rows, 310, 340, 4) == list(range(310, 330))
    armed = [r for r in rows if r[0] >= 330]
    assert armed[0][1] == M.ARMED and all(r[7] == T.NONE for r in armed)
    # in ARMED the starter and igniter are the sequencer's, the pump off in the spin-up
    assert all(r[4] == 0 for r in armed)


# -- over XCP, Python and C slaves alike ------------------------------------------------------
def _err(code: int) -> bytes:
    return bytes((C.PID_ERR, code))


def _unlock(rigs: Rigs) -> None:
    seed = rigs.same(C.Cmd.GET_SEED, 0, C.RES_CAL_PAG)
    key = key_for(seed[2:6])
    assert rigs.same(C.Cmd.UNLOCK, len(key), key)[0] == C.PID_RES


def _write(rigs: Rigs, index: int, value: int) -> bytes:
    address = MEM.bench_address(index)
    assert rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", address)) == b"\xff"
    return rigs.same(C.Cmd.DOWNLOAD, 4, struct.pack("<i", value))


def _read(rigs: Rigs, index: int) -> int:
    res = rigs.same(C.Cmd.SHORT_UPLOAD, 4, 0, 0, struct.pack("<I", MEM.bench_address(index)))
    return struct.unpack("<i", res[1:5])[0]


def _rest(rigs: Rigs, **inputs: int) -> None:
    rigs.set_inputs(sensor_status=E2E_OK, analog_status=E2E_OK, speed_rpm=0, egt_dk=2900,
                    supply_mv=22200, **inputs)  # fmt: skip


def test_xcp_asks_for_a_test_and_the_ecu_times_it_out():
    rigs = Rigs()
    rigs.same(C.Cmd.CONNECT, 0)
    _rest(rigs)
    rigs.ticks(3)
    assert _write(rigs, MEM.BENCH_TEST, T.GLOW) == _err(C.Err.ACCESS_LOCKED)
    _unlock(rigs)
    assert _write(rigs, MEM.BENCH_TEST_LEVEL, 6000) == b"\xff"
    assert _write(rigs, MEM.BENCH_TEST_MS, 400) == b"\xff"
    assert (_read(rigs, MEM.BENCH_TEST_LEVEL), _read(rigs, MEM.BENCH_TEST_MS)) == (6000, 400)
    assert _write(rigs, MEM.BENCH_TEST, T.STARTER) == _err(C.Err.OUT_OF_RANGE)  # > start duty
    assert _write(rigs, MEM.BENCH_TEST, 4) == _err(C.Err.OUT_OF_RANGE)
    assert _write(rigs, MEM.BENCH_TEST_LEVEL, 2000) == b"\xff"
    assert _write(rigs, MEM.BENCH_TEST, T.STARTER) == b"\xff"
    rigs.tick()
    assert _read(rigs, MEM.BENCH_TEST) == T.STARTER
    assert rigs.py_ecu.out.starter_cpct == rigs.c_ecu.out.starter_cpct == 2000
    on = 1  # ticks with the starter on
    while on < 100:
        rigs.tick()
        if not rigs.py_ecu.out.starter_cpct:
            break
        on += 1
    assert on == 400 * RATE // 1000 and rigs.c_ecu.out.starter_cpct == 0
    assert _read(rigs, MEM.BENCH_TEST) == T.NONE
    # the same test again: a new request (the bench dropped the old one when it was over)
    assert _write(rigs, MEM.BENCH_TEST, T.STARTER) == b"\xff"
    rigs.tick()
    assert rigs.py_ecu.out.starter_cpct == rigs.c_ecu.out.starter_cpct == 2000
    # a stop ends it at once; a glow test after the stop runs (the bench takes it)
    assert _write(rigs, MEM.BENCH_STOP, 1) == b"\xff"
    rigs.tick()
    assert rigs.py_ecu.out.starter_cpct == rigs.c_ecu.out.starter_cpct == 0
    assert _write(rigs, MEM.BENCH_TEST, T.GLOW) == b"\xff"
    rigs.ticks(2)
    assert rigs.py_ecu.out.igniter == rigs.c_ecu.out.igniter == 1
    assert _write(rigs, MEM.BENCH_TEST, T.NONE) == b"\xff"  # 0 ends the test
    rigs.tick()
    assert rigs.py_ecu.out.igniter == rigs.c_ecu.out.igniter == 0
    # a pump prime within the ignition's voltage, an arm ends it
    assert _write(rigs, MEM.BENCH_TEST_LEVEL, 1500) == b"\xff"
    assert _write(rigs, MEM.BENCH_TEST, T.PRIME) == b"\xff"
    rigs.tick()
    assert rigs.py_ecu.out.pump_enable == rigs.c_ecu.out.pump_enable == 1
    assert rigs.py_ecu.out.pump_mv == rigs.c_ecu.out.pump_mv == 1500
    assert _write(rigs, MEM.BENCH_ARM, 1) == b"\xff"
    rigs.tick()
    assert rigs.py_ecu.s.test_active == rigs.c_ecu.s.test_active == T.NONE
    assert rigs.py_ecu.out.mode == M.ARMED
    # refused in ARMED, and with the arm held
    assert _write(rigs, MEM.BENCH_TEST, T.GLOW) == _err(C.Err.ACCESS_DENIED)


@pytest.mark.parametrize("mode", [M.RUN, M.FAULT])
def test_refused_in_run_and_fault(mode):
    rigs = Rigs()
    rigs.same(C.Cmd.CONNECT, 0)
    _unlock(rigs)
    rigs.set_inputs(sensor_status=E2E_OK, analog_status=E2E_OK, demand_status=E2E_OK,
                    speed_rpm=100_890, egt_dk=10_480, supply_mv=22_200, pump_ma=1_500,
                    demand_cpct=8_968, arm=1)  # fmt: skip
    rigs.ticks(3)
    if mode == M.FAULT:
        rigs.set_inputs(speed_rpm=130_000)  # overspeed
        rigs.ticks(80)
    assert rigs.py_ecu.out.mode == rigs.c_ecu.out.mode == mode
    assert _write(rigs, MEM.BENCH_TEST_MS, 100) == b"\xff"
    assert _write(rigs, MEM.BENCH_TEST, T.GLOW) == _err(C.Err.ACCESS_DENIED)


def test_refused_while_can_demand_frames_are_present():
    rigs = Rigs()
    rigs.same(C.Cmd.CONNECT, 0)
    _unlock(rigs)
    _rest(rigs, demand_status=E2E_OK, demand_cpct=3500, arm=0)
    rigs.ticks(3)
    assert rigs.py_ecu.out.mode == M.OFF
    assert _write(rigs, MEM.BENCH_TEST_MS, 100) == b"\xff"
    assert _write(rigs, MEM.BENCH_TEST, T.GLOW) == _err(C.Err.ACCESS_DENIED)


def test_the_a2l_lists_the_bench_words_and_the_measurements():
    from ecu.xcp.a2l import a2l_text

    text = a2l_text()
    for name in ("bench_test_level", "bench_test_ms", "bench_test"):
        assert f"/begin CHARACTERISTIC {name} " in text
    assert (
        "/begin MEASUREMENT test_active " in text and "/begin MEASUREMENT test_time_left " in text
    )
    assert '0 "NONE" 1 "GLOW" 2 "STARTER" 3 "PRIME"' in text


# -- the plant sees them -----------------------------------------------------------------------
@pytest.mark.parametrize("impl", ["python", "c"])
def test_a_starter_spin_turns_the_plants_shaft(impl):
    from ecu.node import EcuNode
    from ecu.port.node import CEcuNode
    from ecu.port.xcp import CXcpSlave
    from ecu.service.port import boot
    from ecu.xcp.slave import XcpSlave
    from plant.aerothermal import AeroThermalPlant
    from plant.interface import PlantConfig
    from plant.node import PlantNode
    from protocol.node import InProcessBus

    booted = boot(EcuParams(), None)
    plant = AeroThermalPlant(PlantConfig(standstill=True))
    if impl == "python":
        ecu = Ecu(booted.table.firmware)
        node = EcuNode(ecu=ecu)
        node.attach_xcp(XcpSlave(ecu, booted))
    else:
        ecu = CEcu(booted.table.firmware)
        node = CEcuNode(ecu)
        node.attach_xcp(CXcpSlave(ecu, booted.table))
    plant_node = PlantNode(plant, max_ticks=400)
    speeds = []
    sent = []
    bus = InProcessBus([node, plant_node], tap=lambda f, d: sent.append(f))
    if impl == "python":
        node.xcp.bench.set_test(level=int(P.start_duty * 10000), ms=2000)
        node.xcp.bench.test(T.STARTER)
    else:
        _c_bench_test(node.xcp, int(P.start_duty * 10000), 2000)

    def done() -> bool:
        speeds.append(plant.outputs.n_pct)
        return plant_node.finished

    bus.run(done=done)
    assert ecu.out.mode == M.OFF and ecu.s.test_active == T.NONE
    top = max(speeds)
    assert top > 1.0, top  # the starter spun the rotor
    assert speeds[-1] < top  # and it runs down once the test is over
    assert Codec_starter_id() in sent


def Codec_starter_id() -> int:  # noqa: N802
    from protocol.codec import Codec

    return Codec()["EcuStarter"].frame_id


def _c_bench_test(slave, level: int, ms: int) -> None:  # noqa: ANN001
    """The C slave's bench test words written over XCP frames (unlocked)."""
    answers: list[bytes] = []
    slave._sink = answers.append

    def request(*frame: int | bytes) -> bytes:
        answers.clear()
        slave.receive(b"".join(bytes((x,)) if isinstance(x, int) else x for x in frame))
        slave.serve(answers.append)
        return answers[0]

    request(C.Cmd.CONNECT, 0)
    seed = request(C.Cmd.GET_SEED, 0, C.RES_CAL_PAG)
    key = key_for(seed[2:6])
    request(C.Cmd.UNLOCK, len(key), key)
    for index, value in ((MEM.BENCH_TEST_LEVEL, level), (MEM.BENCH_TEST_MS, ms),
                         (MEM.BENCH_TEST, T.STARTER)):  # fmt: skip
        request(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", MEM.bench_address(index)))
        assert request(C.Cmd.DOWNLOAD, 4, struct.pack("<i", value)) == b"\xff"


def test_the_stage_is_on_the_checked_firmware_path():
    """The no-allocation and integer-only checks run over the test functions' module."""
    from tests.ecu.test_allocation_and_integers import FIRMWARE_MODULES

    assert "actuator_tests" in FIRMWARE_MODULES
