"""The C CAN node (ecu/port/ecu_node.c through ecu/port/node.py) against the Python one
(ecu/node.py): both on a C core from the same parameters, fed the same events, must send the same
frames, byte for byte and in the same order, after every event, and agree on the counters, on
the inputs gathered for the next tick and on the core's state. Events: seeded random streams of
thousands of events and hypothesis-chosen ones (every kind of frame the node handles, valid,
corrupt, repeated, out of order, wrapping; timeouts; periods), and the frames of recorded
lockstep runs, which the C node must also answer exactly as the run's log does."""

from __future__ import annotations

import ctypes
import dataclasses
import random
import re
import struct
import subprocess
from collections import Counter
from functools import cache
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu.firmware import E2E_OK, E2E_REPEATED, E2E_WRONGCRC, E2E_WRONGSEQUENCE, EcuInputs
from ecu.firmware_params import FirmwareParams, compile_params
from ecu.modes import FAULT, RUN
from ecu.node import _TELEMETRY_FIELDS, EcuNode
from ecu.params import PRESETS, EcuParams
from ecu.port import build
from ecu.port.core import CEcu, library
from ecu.port.node import CEcuNode, every, frame_fn_address, node_library
from protocol.codec import Codec
from protocol.e2e import crc8, data_id_crc_start
from protocol.lockstep import TICK_MODULO, every_ticks

PARAMS = {
    "mrac": EcuParams(),
    "pid": EcuParams(controller="pid"),
    "open-loop": PRESETS["sec4_2_estimator"],
    "mrac-fast-250hz": dataclasses.replace(PRESETS["sec5_2_mrac_fast"], rate_hz=250),
    "pid-50hz": EcuParams(controller="pid", rate_hz=50),
    "mrac-1000hz": EcuParams(rate_hz=1000),
}
RECEIVED = ("PlantSensors", "PlantAnalog", "Demand")
OTHER_IDS = (0x110, 0x200, 0x210, 0x300, 0x301, 0x310, 0x7F0, 0x000, 0x7FF, 0x102, 0x081)
CODEC = Codec()  # layouts and IDs only (the nodes' transmit counters live in their own codecs)


@cache
def firmware(name: str) -> FirmwareParams:
    return compile_params(PARAMS[name])


def _send_to(frames: list[tuple[int, bytes]]):  # noqa: ANN202
    return lambda frame_id, data: frames.append((frame_id, bytes(data)))


class Twin:
    """EcuNode and CEcuNode, each on its own C core from the same parameters, run event by
    event and compared after each one."""

    def __init__(self, params: FirmwareParams, *, lockstep: bool) -> None:
        self.py = EcuNode(ecu=CEcu(params), lockstep=lockstep, codec=Codec())
        self.c = CEcuNode(CEcu(params), lockstep=lockstep, codec=CODEC)
        self.history: list[tuple] = []
        self.frames_sent = 0
        self.modes: Counter[int] = Counter()
        self.pending2 = self.waited = self.own_clock = 0

    def run(self, event: tuple) -> list[tuple[int, bytes]]:
        """Feed one event to both nodes; the frames they sent (the same, or the test fails)."""
        a: list[tuple[int, bytes]] = []
        b: list[tuple[int, bytes]] = []
        kind = event[0]
        if kind == "frame":
            self.py.on_frame(event[1], event[2], _send_to(a))
            self.c.on_frame(event[1], event[2], _send_to(b))
        elif kind == "timeout":
            self.py.on_timeout(_send_to(a))
            self.c.on_timeout(_send_to(b))
        elif kind == "period":
            self.py.on_period(_send_to(a))
            self.c.on_period(_send_to(b))
        elif kind == "reset":  # both cores re-initialised (out of a latched FAULT)
            self.py.ecu.reset()
            self.c.ecu.reset()
        else:
            raise AssertionError(event)
        self.history.append(event)
        self.check(a, b)
        self.frames_sent += len(a)
        if a:
            self.modes[self.py.ecu.out.mode] += 1
        self.pending2 += self.py.demand_pending == 2
        self.waited += self.py.waiting
        self.own_clock += self.py.timeout_s is not None
        return a

    def where(self) -> str:
        tail = "\n  ".join(_show(e) for e in self.history[-12:])
        return f"after event {len(self.history) - 1}; the last events:\n  {tail}"

    def check(self, a: list[tuple[int, bytes]], b: list[tuple[int, bytes]]) -> None:
        py, c = self.py, self.c
        if a != b:
            raise AssertionError(
                f"frames differ {self.where()}\n python: {_frames(a)}\n c:      {_frames(b)}"
            )
        for name in ("ticks", "tick", "late_sensor_frames", "demand_waits", "waiting"):
            assert getattr(c, name) == getattr(py, name), f"{name} {self.where()}"
        assert c.timeout_s == py.timeout_s, f"timeout_s {self.where()}"
        assert c.finished is py.finished is False
        for name in EcuInputs.FIELDS:
            assert getattr(c.i, name) == getattr(py.i, name), f"inputs.{name} {self.where()}"
        if a:
            assert c.ecu.digest() == py.ecu.digest(), f"core state {self.where()}"


def _frames(frames: list[tuple[int, bytes]]) -> str:
    return " ".join(f"{i:03X}#{d.hex().upper()}" for i, d in frames) or "(none)"


def _show(event: tuple) -> str:
    if event[0] == "frame":
        return f"frame {event[1]:03X}#{bytes(event[2]).hex().upper()}"
    return event[0]


class Frames:
    """Received frames as any sender could make them: raw values written into their bits as
    they are (beyond the DBC range too), any alive counter, a valid CRC unless corrupted."""

    def __init__(self) -> None:
        self.msgs = {name: CODEC[name] for name in RECEIVED}
        self.counter = dict.fromkeys(RECEIVED, 0)

    def make(self, name: str, raws: list[int], counter: int | None = None) -> bytes:
        m = self.msgs[name]
        word = 0
        for raw, s in zip(raws, m.signals, strict=True):
            word |= (raw & ((1 << s.length) - 1)) << s.start
        if counter is None:  # the sender's next counter
            counter = self.counter[name]
            self.counter[name] = (counter + 1) % 15
        data = bytearray(struct.pack("<Q", word | (counter & 0xF) << 8))
        data[0] = crc8(bytes(data[1:]), data_id_crc_start(m.data_id))
        return bytes(data)


def corrupt(rng: random.Random, data: bytes) -> bytes:
    out = bytearray(data)
    r = rng.random()
    if r < 0.6:
        out[rng.randrange(8)] ^= 1 << rng.randrange(8)  # one flipped bit
    elif r < 0.8:
        out[0] = (out[0] + rng.randrange(1, 256)) % 256  # a wrong CRC byte
    else:
        out = bytearray(rng.randbytes(8))  # noise
    return bytes(out)


def random_stream(rng: random.Random, events: int, rate_hz: int, *, tame: float, lockstep: bool):
    """Events of a plant and a command node, perturbed: ``tame`` (0..1) is the share of plain
    ticks (the next sensor tick, its analog and Demand frames when due); in real time each tick
    of the plant is followed by a period of the ECU's clock (sometimes none, or two)."""
    every_demand = every_ticks(CODEC["Demand"].cycle_time_ms, rate_hz)
    silence = max(30, rate_hz * 2 // 5)  # ticks: beyond the sensor frames' timeout (0.2 s)
    frames = Frames()
    k = rng.choice((0, rng.randrange(TICK_MODULO), TICK_MODULO - rng.randrange(1, 300)))
    speed = rng.randint(95000, 105000)
    arm = 1
    last_counter = dict.fromkeys(RECEIVED, 0)
    n = 0
    for _ in range(rng.randint(0, 3)):  # before any frame: a timeout does nothing, a period ticks
        yield rng.choice((("timeout",), ("period",)))

    def frame(name: str, raws: list[int], perturb: bool) -> tuple:
        counter = None
        if perturb:
            r = rng.random()
            if r < 0.04:
                counter = last_counter[name]  # the same counter again: REPEATED
            elif r < 0.08:
                counter = (last_counter[name] + rng.randrange(2, 15)) % 15  # a gap
            elif r < 0.10:
                counter = 15
        if counter is None:
            counter = frames.counter[name]
            frames.counter[name] = (counter + 1) % 15
        elif counter < 15 and rng.random() < 0.5:
            frames.counter[name] = (counter + 1) % 15  # the sender goes on from there
        last_counter[name] = counter
        data = frames.make(name, raws, counter)
        if perturb and rng.random() < 0.05:
            data = corrupt(rng, data)
        return ("frame", CODEC[name].frame_id, data)

    def demand(tick: int, perturb: bool) -> tuple:
        nonlocal arm
        if rng.random() < 0.01:
            arm ^= 1
        stop = int(rng.random() < 0.005)
        if rng.random() < 0.05:
            cpct, mv = rng.randrange(1 << 16), rng.randrange(1 << 16)  # beyond the DBC range too
        else:
            cpct, mv = rng.randint(8000, 9500), rng.randint(8000, 14000)
        return frame("Demand", [arm, stop, cpct, mv, tick % TICK_MODULO], perturb)

    while n < events:
        r = rng.random()
        out: list[tuple] = []
        perturb = r >= tame
        if r < tame + (1 - tame) / 2:  # a tick of the plant (perturbed or not)
            if k % 5 == 0 and (not perturb or rng.random() < 0.8):
                out.append(frame("PlantAnalog", [k, rng.randint(21000, 24000),
                                                 rng.randint(1000, 2500)], perturb))  # fmt: skip
            # the Demand for tick k + lead (lead = every_demand: due when k is a multiple)
            if k % every_demand == 0 and (not perturb or rng.random() < 0.7):
                lead = every_demand if not perturb or rng.random() < 0.7 else 0
                out.append(demand(k + lead, perturb))
            tick = k
            if perturb:
                p = rng.random()
                if p < 0.25:
                    tick = k - 1  # the last tick again
                elif p < 0.45:
                    tick = k + rng.randint(1, 6)  # ticks skipped
                    k = tick
                elif p < 0.55:
                    tick = k - rng.randint(2, 40000)  # backwards
                elif p < 0.65:
                    tick = k = rng.randrange(TICK_MODULO)  # anywhere
                elif p < 0.7:
                    tick = k = TICK_MODULO - rng.randint(1, 4)  # about to wrap
                elif p < 0.75:
                    tick = k + 40000  # more than half the tick range ahead: behind
            speed = min(max(speed + rng.randint(-150, 150), 90000), 110000)
            rpm = speed if not perturb or rng.random() < 0.9 else rng.randrange(1 << 18)
            egt = rng.randint(10000, 10800) if not perturb or rng.random() < 0.9 else 16383
            out.append(frame("PlantSensors", [tick % TICK_MODULO, rpm, egt], perturb))
            k = (k + 1) % TICK_MODULO
            if not lockstep:
                out += [("period",)] * (1 if not perturb else rng.choice((0, 1, 1, 2)))
        else:
            p = rng.random()
            if p < 0.2:  # a Demand due now, late, ahead, far away
                offset = rng.choice((0, 0, -1, -every_demand, every_demand, 2 * every_demand,
                                     rng.randint(-100, 100), 32768))  # fmt: skip
                out.append(demand(k + offset, perturb=rng.random() < 0.5))
            elif p < 0.4:
                out.append(("timeout",))
                if rng.random() < 0.5:
                    out += [("timeout",)] * rng.randint(1, silence)  # the plant silent a while
            elif p < 0.5:
                out.append(("period",))
                if rng.random() < 0.5:
                    out += [("period",)] * rng.randint(1, silence)  # the plant silent a while
            elif p < 0.6:
                out.append(("frame", rng.choice(OTHER_IDS), rng.randbytes(8)))
            elif p < 0.7:
                name = rng.choice(RECEIVED)
                out.append(("frame", CODEC[name].frame_id, rng.randbytes(8)))
            elif p < 0.8:
                out.append(frame("PlantAnalog", [rng.randrange(1 << 16), rng.randrange(1 << 16),
                                                 rng.randrange(1 << 16)], True))  # fmt: skip
            elif p < 0.85:
                out.append(("reset",))
            else:  # the last frame again, as it was (a repeated frame on the bus)
                out.append(frame("PlantSensors", [(k - 1) % TICK_MODULO, speed, 10400], False))
                out.append(out[-1])
        for event in out:
            yield event
            n += 1


CONFIGS = [(name, lockstep) for name in PARAMS for lockstep in (True, False)]


@pytest.mark.parametrize(("name", "lockstep"), CONFIGS)
def test_random_streams_give_the_same_frames(name, lockstep):
    params = firmware(name)
    statuses: Counter[int] = Counter()
    twins = []
    for seed, tame in ((1, 0.97), (2, 0.85), (3, 0.6)):
        rng = random.Random(f"{name}-{lockstep}-{seed}")
        twin = Twin(params, lockstep=lockstep)
        for event in random_stream(rng, 5000, params.rate_hz, tame=tame, lockstep=lockstep):
            twin.run(event)
            if twin.py.waiting and rng.random() < 0.3:  # the driver's guard time passes
                twin.run(("timeout",))
        for check in (twin.py.sensors_check, twin.py.analog_check, twin.py.demand_check):
            statuses.update({s: n for s, n in enumerate(check.counts) if n})
        twins.append(twin)
    # the streams did what they are for (else this test proves little)
    assert {E2E_OK, E2E_REPEATED, E2E_WRONGSEQUENCE, E2E_WRONGCRC} <= set(statuses), statuses
    assert sum(t.frames_sent for t in twins) > 3000
    modes = sum((t.modes for t in twins), Counter())
    assert modes[RUN] > 100 and modes[FAULT] > 0, modes
    if lockstep:
        assert all(t.py.late_sensor_frames > 0 and t.own_clock > 0 for t in twins)
        assert sum(t.py.demand_waits for t in twins) > 0 and sum(t.waited for t in twins) > 0
        assert sum(t.pending2 for t in twins) > 0
        assert twins[0].py.ticked_demands
    else:
        assert all(t.py.late_sensor_frames == t.py.demand_waits == 0 for t in twins)


# -- hypothesis: short streams, any values -------------------------------------------------------
COUNTER = st.one_of(st.none(), st.none(), st.none(), st.integers(0, 15))
OPS = st.one_of(
    st.tuples(st.just("sensors"), st.sampled_from(("next", "same", "skip", "back", "any")),
              st.integers(0, TICK_MODULO - 1), st.integers(0, (1 << 18) - 1),
              st.integers(0, (1 << 14) - 1), COUNTER, st.booleans()),  # fmt: skip
    st.tuples(st.just("analog"), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF),
              st.integers(0, 0xFFFF), COUNTER, st.booleans()),  # fmt: skip
    st.tuples(st.just("demand"), st.sampled_from(("lead", "due", "late", "ahead", "any")),
              st.integers(0, TICK_MODULO - 1), st.integers(0, 1), st.integers(0, 1),
              st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), COUNTER, st.booleans()),  # fmt: skip
    st.tuples(st.just("timeout")),
    st.tuples(st.just("period")),
    st.tuples(st.just("bytes"), st.sampled_from((*(CODEC[n].frame_id for n in RECEIVED),
                                                 *OTHER_IDS)), st.binary(min_size=8, max_size=8)),
)  # fmt: skip


def _interpret(ops: list[tuple], every_demand: int):  # noqa: ANN202
    frames = Frames()
    k = 0
    for op in ops:
        kind = op[0]
        if kind == "sensors":
            _, how, value, rpm, egt, counter, flip = op
            k = {"next": k + 1, "same": k, "skip": k + 1 + value % 8, "back": k - value % 3000,
                 "any": value}[how] % TICK_MODULO  # fmt: skip
            data = frames.make("PlantSensors", [k, rpm, egt], counter)
        elif kind == "analog":
            _, tick, mv, ma, counter, flip = op
            data = frames.make("PlantAnalog", [tick, mv, ma], counter)
        elif kind == "demand":
            _, how, value, arm, stop, cpct, mv, counter, flip = op
            tick = {"lead": k + every_demand, "due": k, "late": k - value % 50,
                    "ahead": k + 1 + value % 200, "any": value}[how] % TICK_MODULO  # fmt: skip
            data = frames.make("Demand", [arm, stop, cpct, mv, tick], counter)
        elif kind == "bytes":
            yield ("frame", op[1], op[2])
            continue
        else:
            yield (kind,)
            continue
        if flip:
            data = bytes((data[0] ^ 0x5A, *data[1:]))
        yield ("frame", CODEC[{"sensors": "PlantSensors", "analog": "PlantAnalog",
                               "demand": "Demand"}[kind]].frame_id, data)  # fmt: skip


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(sorted(PARAMS)),
    lockstep=st.booleans(),
    ops=st.lists(OPS, max_size=120),
)
def test_any_events_give_the_same_frames(name, lockstep, ops):
    params = firmware(name)
    twin = Twin(params, lockstep=lockstep)
    for event in _interpret(ops, every_ticks(CODEC["Demand"].cycle_time_ms, params.rate_hz)):
        twin.run(event)


# -- recorded runs -------------------------------------------------------------------------------
CANDUMP = re.compile(r"^\((\d+\.\d+)\) \S+ ([0-9A-F]{3})#([0-9A-F]{16})$")
ECU_IDS = (0x110, 0x200, 0x210)


def _record_run(tmp: Path, scenario_name: str, ecu_impl: str, duration_s: float):
    """A scenario run in process through the Python node (on the Python firmware or the C core):
    its parameters and the frames of its can.log."""
    from sil import scenario
    from sil.run import runner

    s = dataclasses.replace(scenario.load(scenario_name), duration_s=duration_s)
    options = runner.RunOptions(
        s, tmp / scenario_name, mode="inproc", plots=False, progress=False, ecu_impl=ecu_impl,
        compiled_loop=False,  # the Python EcuNode writes the reference log
    )  # fmt: skip
    summary = runner.run(options)
    assert summary["status"] == "completed", summary
    plant = runner.build_plant(s, s.seed)
    params = compile_params(runner.ecu_params(s, plant))
    frames = []
    for line in (tmp / scenario_name / "can.log").read_text().splitlines():
        found = CANDUMP.match(line)
        assert found, line
        frames.append((int(found.group(2), 16), bytes.fromhex(found.group(3))))
    return params, frames


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """thesis-5.2-mrac-fast through the Python node on the C core (docs/sil-runs.md's `sil run
    thesis-5.2-mrac-fast --mode inproc --ecu-impl c`, 120 s of it) and thesis-6.1-pid on the
    Python firmware."""
    tmp = tmp_path_factory.mktemp("runs")
    return {
        "mrac-c": _record_run(tmp, "thesis-5.2-mrac-fast", "c", 120.0),
        "pid-python": _record_run(tmp, "thesis-6.1-pid", "python", 60.0),
    }


@pytest.mark.parametrize("run", ["mrac-c", "pid-python"])
def test_recorded_run_gives_the_logged_frames(recorded, run):
    params, frames = recorded[run]
    twin = Twin(params, lockstep=True)
    received = set(twin.py.frame_ids)
    sent: list[tuple[int, bytes]] = []
    for frame_id, data in frames:
        if frame_id in received:
            sent += twin.run(("frame", frame_id, data))
    logged = [f for f in frames if f[0] in ECU_IDS]
    assert len(logged) > 10000 and twin.modes[RUN] > 1000
    # the log ends where the run stopped: at most the last tick's answer is not in it
    assert 0 <= len(sent) - len(logged) <= node_library().max_out
    for n, (a, b) in enumerate(zip(logged, sent, strict=False)):
        assert a == b, f"ECU frame {n}: logged {_frames([a])}, nodes {_frames([b])}"
    assert twin.py.late_sensor_frames == twin.py.demand_waits == 0


def test_recorded_run_with_bus_faults_injected(recorded):
    """The recorded run's frames with a faulty bus between them and the nodes: frames lost,
    repeated, delayed behind later ones, corrupted; timeouts where the plant would wait."""
    params, frames = recorded["mrac-c"]
    twin = Twin(params, lockstep=True)
    received = set(twin.py.frame_ids)
    rng = random.Random(11)
    delayed: list[tuple[int, tuple]] = []
    for n, (frame_id, data) in enumerate(frames):
        if frame_id not in received:
            continue
        r = rng.random()
        events = [("frame", frame_id, data)]
        if r < 0.02:
            events = []  # lost
        elif r < 0.03:
            events *= 2  # repeated
        elif r < 0.04:
            events = [("frame", frame_id, corrupt(rng, data))]
        elif r < 0.05:
            delayed.append((n + rng.randint(1, 40), events[0]))  # overtaken
            events = []
        elif r < 0.052:
            events = [("timeout",)] * rng.randint(1, 15) + events  # a pause of the plant
        elif r < 0.0522:
            # longer: sensor frames lost, FAULT; then the cores power-cycled (FAULT latches)
            events = [("timeout",)] * rng.randint(20, 300) + [("reset",), *events]
        if delayed and delayed[0][0] <= n:
            events.append(delayed.pop(0)[1])
        for event in events:
            twin.run(event)
            if twin.py.waiting and rng.random() < 0.3:
                twin.run(("timeout",))
    assert twin.py.late_sensor_frames > 0 and twin.py.demand_waits > 0 and twin.own_clock > 0
    assert twin.modes[RUN] > 1000


# -- the pieces --------------------------------------------------------------------------------
def test_every_is_every_ticks():
    for cycle in range(1, 1001):
        for rate in range(1, 1001):
            assert every(cycle, rate) == every_ticks(cycle, rate), (cycle, rate)
    rng = random.Random(4)
    for _ in range(20000):
        cycle, rate = rng.randrange(1 << 32), rng.choice((rng.randrange(1, 1 << 32), 1000))
        assert every(cycle, rate) == min(every_ticks(cycle, rate), 0xFFFF), (cycle, rate)
    assert every(0, 100) == every(50, 0) == 1  # (every_ticks refuses a rate of 0)


def test_frame_helper_packs_as_the_codec():
    codec, frames = Codec(), Frames()
    rng = random.Random(2)
    for _ in range(300):
        name = rng.choice(RECEIVED)
        m = codec[name]
        raws = [rng.randint(s.raw_min, s.raw_max) for s in m.signals]
        m.pack_raw(raws)
        assert frames.make(name, raws) == bytes(m.data)


def test_telemetry_saturates_as_the_codec():
    """The Q7.24 telemetry values at the ends of int32: the DBC range stops at 2**31 - 2."""
    lib = library().lib
    telemetry = Codec()["EcuTelemetry"]
    ecu = CEcu()
    fr = (ctypes.c_uint8 * 16)()  # an ecu_frames_t (7 bytes), zeroed: counters 0
    lib.ecu_frames_init(fr)
    data = (ctypes.c_uint8 * 8)()
    names = (*_TELEMETRY_FIELDS, "obs_n_q24", "obs_v_q24", "sat_events")  # indices 0..12
    for value in (2**31 - 1, 2**31 - 2, -(2**31), 0, -1):
        for j, field in enumerate(names):
            setattr(ecu.s if field.startswith("obs") else ecu.out, field, value)
            lib.ecu_frames_telemetry(fr, ctypes.byref(ecu._ecu), data)
            telemetry.pack_raw([j, value])
            assert bytes(data) == bytes(telemetry.data), (field, value)


def test_e2e_counter_15_with_a_valid_crc_as_the_python_checker():
    """A frame with counter 15 and a valid CRC is WRONGCRC, and the next frame is judged from the
    counter before it (nothing of a corrupted frame is remembered), in C as in E2EChecker."""
    lib = library().lib
    lib.ecu_frames_check.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_char_p]
    lib.ecu_frames_check.restype = ctypes.c_int
    frames = Frames()
    for first in range(15):
        for after in range(16):
            fr = (ctypes.c_uint8 * 16)()
            lib.ecu_frames_init(fr)
            check = CODEC["PlantSensors"].checker(max_delta=2)
            for counter in (first, 15, after, after):
                data = frames.make("PlantSensors", [1, 2, 3], counter)
                assert lib.ecu_frames_check(fr, 0x100, data) == check.check(data), counter
    assert lib.ecu_frames_check(fr, 0x110, bytes(8)) == -1


def test_frame_function_by_address_and_node_buffer():
    """What a compiled caller uses: ecu_node_frame at frame_fn_address(), the node at .address."""
    params = firmware("mrac")
    nl = node_library()
    fn = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_char_p,
                          ctypes.c_void_p)(frame_fn_address())  # fmt: skip
    by_address = CEcuNode(CEcu(params))
    by_method = CEcuNode(CEcu(params))
    out = (nl.frame_t * nl.max_out)()
    sensors = Codec()["PlantSensors"]
    got: list[tuple[int, bytes]] = []
    for k in range(30):
        sensors.pack_raw([k, 100000, 10400])
        n = fn(by_address.address, 0x100, bytes(sensors.data), ctypes.addressof(out))
        got += [(out[j].id, bytes(out[j].data)) for j in range(n)]
    expected: list[tuple[int, bytes]] = []
    sensors = Codec()["PlantSensors"]
    for k in range(30):
        sensors.pack_raw([k, 100000, 10400])
        by_method.on_frame(0x100, sensors.data, _send_to(expected))
    assert got == expected and len(got) == 30 + 6 + 30
    assert by_address.ticks == 30 and by_address.tick == 29
    with pytest.raises(ValueError, match="8"):
        by_method.on_frame(0x100, bytes(7), _send_to(expected))
    by_method.on_frame(0x123, bytes(3), _send_to(expected))  # another ID: ignored


def test_node_object_is_plain_integer_c(toolchains):
    """ecu_node.o for the Cortex-M4 calls only the core, the frame code and the generated
    unpackers; the source has no floating point and no heap."""
    obj = build.arm_objects()["ecu_node.c"]
    undefined = subprocess.run(
        ["arm-none-eabi-nm", "-u", str(obj)], capture_output=True, text=True, check=True
    ).stdout.split()[1::2]
    assert undefined and all(re.match(r"(ecu_|turbojet_)", s) for s in undefined), undefined
    for name in ("ecu_node.c", "ecu_node.h"):
        text = re.sub(r"/\*.*?\*/", "", (build.PORT_DIR / name).read_text(), flags=re.S)
        for word in ("float", "double", "malloc", "free(", "<math.h>", "<stdlib.h>"):
            assert word not in text, (name, word)
