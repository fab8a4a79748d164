"""The C XCP slave (ecu/port/ecu_xcp.c) against the Python one (ecu/xcp/slave.py): the same
request sequences, the hypothesis-generated bad input of test_robustness.py among them, give the
same answer frames, DTOs and counters, and the two ECUs tick alike. A Python slave given the C
slave's limits (ecu.port.xcp.c_limits) and seeds (XorShiftSeeds) is its reference.

Writes: every parameter the C slave writes, at and around its limits and at random, in OFF and in
RUN, single and in master blocks, is answered as the Python slave answers it, and an accepted one
leaves the C core's parameter words equal to compile_params' of the Python slave's set (at several
rates, in both readings). The commissioning parameters (ecu.port.xcp_run.COMMISSIONING) are
ERR_WRITE_PROTECTED on C, as docs/calibration.md says."""

from __future__ import annotations

import ctypes
import importlib.util
import random
import re
import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu.firmware import E2E_NONEWDATA, EcuInputs
from ecu.params import EcuParams, preset
from ecu.port.core import CEcu, library, param_words
from ecu.port.xcp import CXcpSlave, XorShiftSeeds, c_limits
from ecu.port.xcp_run import COMMISSIONING, INDEX, bounds, writable
from ecu.service.param_table import TABLE
from ecu.service.port import boot
from ecu.service.storage import FlashImage
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import key_for
from ecu.xcp.slave import XcpSlave

_spec = importlib.util.spec_from_file_location(
    "xcp_robustness", Path(__file__).with_name("test_robustness.py")
)
robustness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(robustness)

SETTINGS = settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
SEED = 3


class Rigs:
    """The Python slave on the Python firmware and the C slave on the C core, one parameter set,
    fed the same frames and inputs; each call returns (Python's packets, C's packets)."""

    def __init__(self, params: EcuParams | None = None, flash: tuple[Path, Path] | None = None):
        params = params or EcuParams()
        py_flash, c_flash = flash or (None, None)
        self.py_boot = boot(params, py_flash)
        c_boot = boot(params, None)
        from ecu.firmware import Ecu

        self.py_ecu = Ecu(self.py_boot.table.firmware)
        self.py = XcpSlave(self.py_ecu, self.py_boot, seed=0, limits=c_limits())
        self.py._rng = XorShiftSeeds(SEED)
        self.c_ecu = CEcu(c_boot.table.firmware)
        c_image = FlashImage(c_flash) if c_flash is not None else None
        self.c = CXcpSlave(self.c_ecu, c_boot.table, seed=SEED, flash=c_image)
        self.i = EcuInputs()
        self.i.sensor_status = self.i.analog_status = self.i.demand_status = E2E_NONEWDATA
        self.ci = EcuInputs()
        self._cin = library().inputs_t()
        self.copy_inputs()

    def copy_inputs(self) -> None:
        for name in EcuInputs.FIELDS:
            setattr(self.ci, name, getattr(self.i, name))

    def receive(self, frame: bytes) -> None:
        self.py.receive(frame)
        self.c.receive(frame)

    def serve(self) -> tuple[list[bytes], list[bytes]]:
        a: list[bytes] = []
        b: list[bytes] = []
        self.py.serve(a.append)
        self.c.serve(b.append)
        return a, b

    def request(self, *frame: int | bytes) -> tuple[bytes, bytes]:
        data = b"".join(bytes((x,)) if isinstance(x, int) else x for x in frame)
        self.receive(data)
        a, b = self.serve()
        assert a == b, (data.hex(), a, b)
        return (a[0] if a else b""), (b[0] if b else b"")

    def same(self, *frame: int | bytes) -> bytes:
        a, b = self.request(*frame)
        assert a == b
        return a

    def tick(self) -> list[bytes]:
        a, b = self.serve()
        self.py_ecu.tick(self.py.inputs(self.i))
        cin = self._cin
        for name in EcuInputs.FIELDS:
            setattr(cin, name, getattr(self.ci, name))
        ptr = self.c.inputs_c(cin)
        library().lib.ecu_tick(ctypes.byref(self.c_ecu._ecu), ptr)
        for name in EcuInputs.FIELDS:
            setattr(self.ci, name, getattr(cin, name))
        self.py.sample(a.append)
        self.c.sample(b.append)
        for i in (self.i, self.ci):
            i.sensor_status = i.analog_status = i.demand_status = E2E_NONEWDATA
        assert a == b, (a, b)
        self.check_ecus()
        return a

    def ticks(self, n: int) -> list[bytes]:
        out = []
        for _ in range(n):
            out += self.tick()
        return out

    def check_ecus(self) -> None:
        for name in ("mode", "pump_mv", "duty_cpct", "fault_word", "nref_cpct", "owner",
                     "seq_state", "sat_events"):  # fmt: skip
            assert getattr(self.py_ecu.out, name) == getattr(self.c_ecu.out, name), name
        assert self.py_ecu.s.stop == self.c_ecu.s.stop

    def check_params(self) -> None:
        """The C slave's raws are the Python table's, its core's words compile_params' of it."""
        assert self.c.raws() == self.py_boot.table.raws()
        words = param_words(self.py_ecu.p)
        got = list(ctypes.cast(ctypes.byref(self.c_ecu._params),
                               ctypes.POINTER(ctypes.c_int32 * len(words))).contents)  # fmt: skip
        diff = [k for k, (a, b) in enumerate(zip(words, got, strict=True)) if a != b]
        assert not diff, [(k, words[k], got[k]) for k in diff]

    def set_inputs(self, **values: int) -> None:
        for name, value in values.items():
            setattr(self.i, name, value)
            setattr(self.ci, name, value)

    def engine_running(self) -> None:
        self.set_inputs(sensor_status=0, analog_status=0, demand_status=0, speed_rpm=100_890,
                        egt_dk=10_480, supply_mv=22_200, pump_ma=1_500, demand_cpct=8_968,
                        arm=1, stop=0)  # fmt: skip

    def at_rest(self) -> None:
        self.set_inputs(sensor_status=0, analog_status=0, demand_status=E2E_NONEWDATA,
                        speed_rpm=0, egt_dk=2_900, supply_mv=22_200, pump_ma=0)  # fmt: skip

    def connect(self) -> None:
        assert self.same(C.Cmd.CONNECT, 0)[0] == C.PID_RES

    def unlock(self, resource: int) -> None:
        seed = self.same(C.Cmd.GET_SEED, 0, resource)
        assert seed[:2] == bytes((C.PID_RES, 4))
        key = key_for(seed[2:6])
        self.same(C.Cmd.UNLOCK, len(key), key)

    def counters(self) -> None:
        p, c = self.py.summary(), self.c.summary()
        for key in ("frames", "served", "responses", "errors", "ignored_not_connected",
                    "empty_frames", "queue_overflow", "blocks_aborted", "events", "stores",
                    "daq_samples", "dtos", "ticks"):  # fmt: skip
            assert p[key] == c[key], (key, p[key], c[key])


# -- the hypothesis-generated bad input of test_robustness.py ----------------------------------
@SETTINGS
@given(robustness.frames, st.booleans(), st.booleans(), st.booleans())
def test_random_frames_get_the_same_answers(batch, unlock_daq, unlock_cal, running):
    rigs = Rigs()
    scenario = rigs.engine_running if running else rigs.at_rest
    scenario()
    rigs.connect()
    if unlock_daq:
        rigs.unlock(C.RES_DAQ)
    if unlock_cal:
        rigs.unlock(C.RES_CAL_PAG)
    for k, frame in enumerate(batch):
        rigs.receive(frame)
        if k % 3 == 0:
            scenario()
            rigs.tick()
    scenario()
    rigs.tick()
    rigs.counters()
    rigs.check_params()


def test_every_command_at_every_length_gets_the_same_answer():
    for pad in (0x00, 0xFF, 0x01):
        rigs = Rigs()
        rigs.connect()
        rigs.unlock(C.RES_CAL_PAG)
        rigs.unlock(C.RES_DAQ)
        for code in [*(int(c) for c in C.Cmd), 0x00, 0xC0, 0xFA]:
            if code in (C.Cmd.DISCONNECT, C.Cmd.CONNECT, C.Cmd.UNLOCK):
                continue
            for length in range(1, 9):
                rigs.request(bytes((code,)) + bytes((pad,)) * (length - 1))
                rigs.tick()
        rigs.counters()


@SETTINGS
@given(robustness.addresses, st.integers(0, 9), st.sampled_from([C.Cmd.SHORT_UPLOAD, 0]))
def test_uploads_and_checksums_anywhere_get_the_same_answers(address, size, kind):
    rigs = Rigs()
    rigs.at_rest()
    rigs.tick()
    rigs.connect()
    rigs.same(C.Cmd.SHORT_UPLOAD, size, 0, 0, struct.pack("<I", address))
    rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", address))
    rigs.same(C.Cmd.UPLOAD, size)
    rigs.same(C.Cmd.BUILD_CHECKSUM, 0, 0, 0, struct.pack("<I", size * 37))


def test_the_whole_map_uploads_alike_over_a_start():
    rigs = Rigs()
    rigs.at_rest()
    rigs.connect()
    rigs.unlock(C.RES_CAL_PAG)
    rigs.ticks(3)
    assert rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", MEM.bench_address(0))) == b"\xff"
    rigs.same(C.Cmd.DOWNLOAD, 4, struct.pack("<i", 1))  # the bench arms: a start from rest
    regions = [(MEM.CAL_BASE, 4 * len(TABLE)), (MEM.MEAS_BASE, MEM.MEAS_SIZE),
               (MEM.BENCH_BASE, 12), (MEM.AXIS_BASE, 48), (MEM.TEXT_BASE, 81)]  # fmt: skip
    for tick in range(300):
        rigs.at_rest()
        rigs.set_inputs(speed_rpm=min(tick * 150, 30_000), egt_dk=2_900 + 10 * min(tick, 200))
        rigs.tick()
        if tick % 50 == 0:
            for base, size in regions:
                rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", base))
                for _ in range(0, size, 7):
                    rigs.same(C.Cmd.UPLOAD, 7 if size >= 7 else size)
                rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", base))
                rigs.same(C.Cmd.BUILD_CHECKSUM, 0, 0, 0, struct.pack("<I", size))


@SETTINGS
@given(
    st.lists(st.integers(0, 20), min_size=1, max_size=20),
    st.lists(st.tuples(robustness.addresses, st.integers(0, 9)), min_size=1, max_size=30),
    st.lists(st.tuples(st.integers(0, 1), st.integers(0, 4)), min_size=20, max_size=20),
)
def test_daq_lists_that_fit_and_do_not_fit_alike(odts, entries, modes):
    rigs = Rigs()
    rigs.at_rest()
    rigs.connect()
    rigs.unlock(C.RES_DAQ)
    rigs.same(C.Cmd.FREE_DAQ)
    rigs.same(C.Cmd.ALLOC_DAQ, 0, struct.pack("<H", len(odts)))
    for n, count in enumerate(odts):
        rigs.same(C.Cmd.ALLOC_ODT, 0, struct.pack("<H", n), count)
    for n, count in enumerate(odts):
        for j in range(min(count, 3)):
            rigs.same(C.Cmd.ALLOC_ODT_ENTRY, 0, struct.pack("<H", n), j, 1 + (n + j) % 3)
    for k, (address, size) in enumerate(entries):
        n = k % len(odts)
        rigs.same(C.Cmd.SET_DAQ_PTR, 0, struct.pack("<H", n), k % 2, k % 3)
        rigs.same(struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, size, 0, address))
        rigs.same(C.Cmd.READ_DAQ)
    for n in range(len(odts)):
        event, prescaler = modes[n]
        rigs.same(struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, n, event, prescaler, 0))
        rigs.same(C.Cmd.GET_DAQ_LIST_MODE, 0, struct.pack("<H", n))
        rigs.same(C.Cmd.GET_DAQ_LIST_INFO, 0, struct.pack("<H", n))
        rigs.same(C.Cmd.START_STOP_DAQ_LIST, 2 if n % 3 else 1, struct.pack("<H", n))
    rigs.same(C.Cmd.START_STOP_SYNCH, 1)
    for _ in range(25):
        rigs.at_rest()
        rigs.tick()
    rigs.same(C.Cmd.CLEAR_DAQ_LIST, 0, struct.pack("<H", 0))
    rigs.same(C.Cmd.START_STOP_SYNCH, 0)
    rigs.counters()


# -- writes ------------------------------------------------------------------------------------
def err(code: int) -> bytes:
    return bytes((C.PID_ERR, code))


def _download(rigs: Rigs, index: int, words: list[int], same: bool = True):  # noqa: ANN202
    """DOWNLOAD (one frame, or a master block) at parameter ``index``: the answer, required the
    same from both slaves (``same``), else both answers."""
    data = struct.pack(f"<{len(words)}i", *words)
    assert rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", MEM.parameter_address(index)))
    frames = [bytes((C.Cmd.DOWNLOAD, len(data))) + data[:6]]
    frames += [
        bytes((C.Cmd.DOWNLOAD_NEXT, len(data) - at)) + data[at : at + 6]
        for at in range(6, len(data), 6)
    ]
    for frame in frames:
        rigs.receive(frame)
    a, b = rigs.serve()
    if same:
        assert a == b, (index, words, a, b)
        return a[0] if a else b""
    return (a[0] if a else b""), (b[0] if b else b"")


def _candidates(spec, current: int, rng: random.Random) -> list[int]:  # noqa: ANN001
    lo, hi = spec.raw_lo, spec.raw_hi
    out = [lo, hi, lo - 1, hi + 1, current + 1, current - 1, (lo + hi) // 2, current]
    return out + [rng.randint(lo, hi) for _ in range(6)]


PARAMS = [
    pytest.param(EcuParams(), id="default"),
    pytest.param(preset("sec5_2_mrac_fast_reproducing"), id="reproducing"),
    pytest.param(preset("default", rate_hz=64), id="64Hz"),
    pytest.param(preset("sec4_2_estimator", rate_hz=250), id="250Hz"),
]


@pytest.mark.parametrize("params", PARAMS)
def test_every_parameter_is_written_alike(params):
    """Each parameter the C slave writes, one at a time, at its limits, just outside, around its
    value and at random, the engine stopped: the same answer, and an accepted write leaves the C
    core with compile_params' words of the Python slave's set."""
    rng = random.Random(7)
    rigs = Rigs(params)
    rigs.at_rest()
    rigs.connect()
    rigs.unlock(C.RES_CAL_PAG)
    allowed = writable(params)
    answers: set[bytes] = set()
    for k, spec in enumerate(TABLE):
        if spec.name not in allowed:
            continue
        for raw in _candidates(spec, rigs.py_boot.table.raws()[k], rng):
            answers.add(_download(rigs, k, [raw]))
            rigs.check_params()
        rigs.at_rest()
        rigs.tick()
    assert answers >= {b"\xff", err(C.Err.OUT_OF_RANGE), err(C.Err.VERIFY)}
    rigs.counters()


@pytest.mark.parametrize("params", PARAMS[:2])
def test_the_run_bounds_and_recipes_hold_at_every_raw_near_their_edges(params):
    """The bounds the run puts on a parameter (a gain's p22 dt, idle against run entry, ...) and
    the recipes' roundings, checked raw by raw around each edge."""
    rigs = Rigs(params)
    rigs.connect()
    rigs.unlock(C.RES_CAL_PAG)
    for name, lo, hi in bounds(params):
        k = INDEX[name]
        for raw in (*range(lo - 3, lo + 4), *range(hi - 3, hi + 4)):
            _download(rigs, k, [raw])
            rigs.check_params()


@SETTINGS
@given(st.integers(0, len(TABLE) - 1), st.integers(1, 12), st.randoms(use_true_random=False))
def test_blocks_of_parameters_are_written_alike(first, count, rng):
    """Consecutive parameters in one master block, near their values or anywhere in their
    limits: the set checked as a whole the same way (the rules among them: ERR_VERIFY)."""
    rigs = Rigs()
    rigs.at_rest()
    rigs.connect()
    rigs.unlock(C.RES_CAL_PAG)
    count = min(count, len(TABLE) - first)
    allowed = writable(EcuParams())
    raws = rigs.py_boot.table.raws()
    words = []
    for k in range(first, first + count):
        spec = TABLE[k]
        if spec.name not in allowed:
            words.append(raws[k])  # unchanged: no write of it
        elif rng.random() < 0.5:
            words.append(raws[k] + rng.randint(-(1 << spec.frac_bits), 1 << spec.frac_bits))
        else:
            words.append(rng.randint(spec.raw_lo, spec.raw_hi))
    _download(rigs, first, words)
    rigs.check_params()
    rigs.tick()


def test_schedules_are_written_whole_or_refused_alike():
    rigs = Rigs()
    rigs.connect()
    rigs.unlock(C.RES_CAL_PAG)
    raws = rigs.py_boot.table.raws()
    for name in ("accel_line_v", "decel_floor_v", "accel_rate_pct_s"):
        k = INDEX[f"{name}[0]"]
        for shift in (2 << 24, -(1 << 23), 7 << 24, -(9 << 24)):
            _download(rigs, k, [raws[k + j] + shift for j in range(12)])
            rigs.check_params()
        falling = _download(rigs, k, list(reversed(raws[k : k + 12])))
        assert falling == (b"\xff" if name == "accel_rate_pct_s" else err(C.Err.VERIFY))


def test_writes_in_run_are_refused_or_taken_alike():
    rigs = Rigs()
    rigs.connect()
    rigs.unlock(C.RES_CAL_PAG)
    for _ in range(20):
        rigs.engine_running()
        rigs.tick()
    assert rigs.py_ecu.out.mode == 2  # RUN
    rng = random.Random(3)
    allowed = writable(EcuParams())
    for k, spec in enumerate(TABLE):
        if spec.name in allowed:
            raw = rigs.py_boot.table.raws()[k]
            _download(rigs, k, [raw + 1 if raw < spec.raw_hi else raw - 1])
            _download(rigs, k, [rng.randint(spec.raw_lo, spec.raw_hi)])
            rigs.check_params()
        rigs.engine_running()
        rigs.tick()


def test_the_commissioning_parameters_are_write_protected_on_c():
    """What docs/calibration.md says the C slave does not write: ERR_WRITE_PROTECTED where the
    Python slave takes the write or refuses it as a set (ERR_VERIFY); limits and RUN are checked
    first, alike."""
    for name in COMMISSIONING:
        rigs = Rigs()
        rigs.connect()
        rigs.unlock(C.RES_CAL_PAG)
        k = INDEX[name]
        spec = TABLE[k]
        assert _download(rigs, k, [spec.raw_hi + 1]) == err(C.Err.OUT_OF_RANGE)
        raw = rigs.py_boot.table.raws()[k]
        assert _download(rigs, k, [raw]) == b"\xff"  # unchanged: no write
        new = raw + 1 if raw < spec.raw_hi else raw - 1
        py, c = _download(rigs, k, [new], same=False)
        assert c == err(C.Err.WRITE_PROTECTED) and py in (b"\xff", err(C.Err.VERIFY)), (name, py)


def test_the_c_a2l_marks_read_only_exactly_what_the_c_slave_refuses_to_write():
    """`sil a2l --impl c|pil` offers no parameter its slave refuses: the parameters the C slave
    answers with ERR_WRITE_PROTECTED (a change of one raw count, in OFF, unlocked) are the
    READ_ONLY ones of its A2L; the Python slave's A2L has none."""
    from sil.commands.a2l import text_for

    def read_only(text: str) -> set[str]:
        blocks = re.findall(r"/begin CHARACTERISTIC (\w+) .*?/end CHARACTERISTIC", text, re.S)
        bodies = re.split(r"/begin CHARACTERISTIC ", text)[1:]
        return {name for name, body in zip(blocks, bodies, strict=True) if "READ_ONLY" in body}

    refused = set()
    for k, spec in enumerate(TABLE):
        if spec.element not in (None, 0):
            continue
        rigs = Rigs()
        rigs.connect()
        rigs.unlock(C.RES_CAL_PAG)
        raw = rigs.py_boot.table.raws()[k]
        new = raw + 1 if raw < spec.raw_hi else raw - 1
        if _download(rigs, k, [new], same=False)[1] == err(C.Err.WRITE_PROTECTED):
            refused.add(spec.name)
    assert refused >= set(COMMISSIONING)
    assert read_only(text_for("c", None, None)) == read_only(text_for("pil", None, None)) == refused
    assert not read_only(text_for("python", None, None)) & {spec.name for spec in TABLE}


def test_the_bench_is_commanded_alike():
    rigs = Rigs()
    rigs.connect()
    arm, stop, throttle = (MEM.bench_address(k) for k in range(3))

    def bench(address: int, value: int) -> bytes:
        rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", address))
        return rigs.same(C.Cmd.DOWNLOAD, 4, struct.pack("<i", value))

    rigs.ticks(3)
    assert bench(arm, 1) == err(C.Err.ACCESS_LOCKED)
    rigs.unlock(C.RES_CAL_PAG)
    assert bench(arm, 1) == err(C.Err.ACCESS_DENIED)  # no readings yet
    for tick in range(600):
        rigs.at_rest()
        rigs.set_inputs(speed_rpm=min(tick * 120, 40_000), egt_dk=2_900 + 20 * min(tick, 150))
        if 400 <= tick < 420:  # CAN Demand frames for a while: they win
            rigs.set_inputs(demand_status=0, demand_cpct=5_000, arm=1)
        rigs.tick()
        if tick in (2, 3, 100, 150, 300, 405, 450, 500):
            bench(arm, tick % 2)
            bench(throttle, (tick * 37) % 13_000 - 100)
            bench(arm, 2)
            rigs.same(C.Cmd.SHORT_UPLOAD, 4, 0, 0, struct.pack("<I", MEM.BENCH_BASE + 8))
            rigs.same(C.Cmd.SHORT_UPLOAD, 1, 0, 0, struct.pack("<I", MEM.measurement_address(
                MEM.MEAS_INDEX["demand_source"])))  # fmt: skip
        if tick in (250, 520):
            bench(stop, 1)
            rigs.connect()  # locked again: a stop is still taken
            bench(stop, 1)
            rigs.unlock(C.RES_CAL_PAG)
    assert rigs.py.bench.source == rigs.c.source
    rigs.counters()


def test_a_store_to_flash_is_answered_alike(tmp_path):
    rigs = Rigs(flash=(tmp_path / "py.bin", tmp_path / "c.bin"))
    rigs.connect()
    assert rigs.same(C.Cmd.SET_REQUEST, 1, 0, 0) == err(C.Err.ACCESS_LOCKED)
    rigs.unlock(C.RES_CAL_PAG)
    assert _download(rigs, INDEX["egt_limit_k"], [1210 << 16]) == b"\xff"
    assert rigs.same(C.Cmd.SET_REQUEST, 1, 0, 0) == b"\xff"
    assert rigs.same(C.Cmd.SET_REQUEST, 1, 0, 0) == err(C.Err.CMD_BUSY)
    events = [f for _ in range(40) for f in rigs.tick() if f[0] == C.PID_EV]
    assert events == [bytes((C.PID_EV, C.Ev.STORE_CAL))]
    assert (tmp_path / "py.bin").read_bytes() == (tmp_path / "c.bin").read_bytes()
    rigs.counters()
    no_flash = Rigs()
    no_flash.connect()
    no_flash.unlock(C.RES_CAL_PAG)
    assert no_flash.same(C.Cmd.SET_REQUEST, 1, 0, 0) == err(C.Err.ACCESS_DENIED)


# -- the slave's IEEE arithmetic in integers ---------------------------------------------------
def _fl(op: int, a: float, b: float | int) -> int:
    lib = library().lib
    lib.ecu_xcp_fl.argtypes = [ctypes.c_int, ctypes.c_uint64, ctypes.c_uint64]
    lib.ecu_xcp_fl.restype = ctypes.c_uint64
    bits_b = b if op == 2 else struct.unpack("<Q", struct.pack("<d", b))[0]
    return lib.ecu_xcp_fl(op, struct.unpack("<Q", struct.pack("<d", a))[0], bits_b & (2**64 - 1))


def _bits(x: float) -> int:
    return struct.unpack("<Q", struct.pack("<d", x))[0]


doubles = st.floats(min_value=1e-12, max_value=1e12) | st.integers(1, 1 << 53).map(float)
signed = st.builds(lambda x, neg: -x if neg else x, doubles, st.booleans())


@settings(max_examples=3000, deadline=None)
@given(signed, signed)
def test_products_and_quotients_are_the_hosts_doubles(a, b):
    assert _fl(0, a, b) == _bits(a * b)
    assert _fl(1, a, b) == _bits(a / b)


@settings(max_examples=3000, deadline=None)
@given(signed, st.integers(-40, 40))
def test_rounding_to_an_integer_is_pythons_round(a, k):
    exact = round(a * 2.0**k)
    got = _fl(2, a, k)
    if -(1 << 31) <= exact < 1 << 31:
        assert got == exact & 0xFFFF_FFFF
    else:
        assert got == 1 << 63


def test_rounding_ties_go_to_even():
    for a in (0.5, 1.5, 2.5, -0.5, -2.5, 1 + 2**-52, 3 * 2**-25):
        for k in (0, 1, 24):
            assert _fl(2, a, k) == round(a * 2.0**k) & 0xFFFF_FFFF, (a, k)
