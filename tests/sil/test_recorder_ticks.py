"""Recorder.record_ticks: whole ticks at once, in canonical order, give the files and figures of
the same frames recorded one by one as the command node records them, byte for byte."""

import dataclasses
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

import sil.record.recorder as recorder_module
from protocol.codec import Codec
from protocol.e2e import crc8, data_id_crc_start
from sil import scenario
from sil.record.recorder import Recorder
from sil.record.ticks import ACTUATOR, SENSORS, InOrderTicks
from sil.record.trace_writer import TraceWriter
from sil.run import runner
from sil.run.recorder_process import RecorderFailed, RecorderProcess
from sil.run.runner import RunOptions

COMMANDS = (0x080, 0x310)  # the command node's frames: Demand, FaultInject
PERIOD_S = 0.01


class Frames:
    """A run's frames in log (canonical) order."""

    def __init__(self, ids: list[int], datas: list[bytes]) -> None:
        self.ids = np.array(ids, np.int64)
        self.datas = datas
        self.payload = np.frombuffer(b"".join(datas), np.uint8).reshape(-1, 8)
        self.ends = np.flatnonzero(self.ids == ACTUATOR) + 1  # each tick's end
        self.prefix = int(self.ends[0])  # the first demands and tick 0: one by one
        self.commands = np.linspace(70.0, 95.0, len(self.ends) + 3)

    @classmethod
    def from_log(cls, path: Path) -> "Frames":
        ids, datas = [], []
        for line in path.read_text().splitlines():
            frame_id, data = line.split()[2].split("#")
            ids.append(int(frame_id, 16))
            datas.append(bytes.fromhex(data))
        return cls(ids, datas)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, tuple[Frames, Path]]:
    """Two in-process runs: the MRAC square wave (two chunks and a bit), and the pump failure
    with its fault injection (FaultInject frames before their demand)."""
    out = {}
    for name, duration in (("thesis-5.2-mrac-fast", 45.0), ("thesis-6.3-failure-mrac", 32.0)):
        s = dataclasses.replace(scenario.load(name), duration_s=duration)
        path = tmp_path_factory.mktemp(name)
        summary = runner.run(RunOptions(s, path, mode="inproc", plots=False, progress=False))
        assert summary["status"] == "completed"
        out[name] = (Frames.from_log(path / "can.log"), path / "can.log")
    return out


def _one_by_one(rec, ids: list[int], datas: list[bytes]) -> None:
    """As the command node: each frame recorded, commands_sent() after the command node's frames
    on each PlantSensors."""
    after_sensors = False
    for frame_id, data in zip(ids, datas, strict=True):
        if after_sensors and frame_id not in COMMANDS:
            rec.commands_sent()
            after_sensors = False
        rec.record(frame_id, data)
        after_sensors = after_sensors or frame_id == SENSORS
    if after_sensors:
        rec.commands_sent()


def _state(rec: Recorder) -> dict:
    trackers = {
        name: tuple(getattr(t, f) for f in t.__slots__)
        for name, t in (("sensor", rec.sensor_ticks), ("actuator", rec.actuator_ticks))
    }
    return {
        "e2e": {m: dict(c) for m, c in rec.e2e.items()},
        "e2e_order": list(rec.e2e),
        "unknown_ids": list(rec.unknown_ids.items()),
        "trackers": trackers,
        "latest_sensor_tick": rec.latest_sensor_tick,
        "unwrapped": (rec._sensor_wrap.last, rec._actuator_wrap.last),  # what record() reads on
        "tick": rec.tick,
        "rows": rec.rows,
        "frames": rec.frames,
    }


def _result(rec: Recorder, out: Path) -> dict:
    before = _state(rec)
    rec.close()
    return {
        "state": before,
        "totals": rec.totals(),
        "can.log": (out / "can.log").read_bytes(),
        "trace.csv": (out / "trace.csv").read_bytes(),
    }


def _recorder(out: Path, frames: Frames) -> Recorder:
    out.mkdir()
    return Recorder(out, Codec(), PERIOD_S, commands=frames.commands)


def _reference(out: Path, frames: Frames) -> dict:
    rec = _recorder(out, frames)
    _one_by_one(rec, frames.ids.tolist(), frames.datas)
    return _result(rec, out)


def _in_blocks(rec, frames: Frames, sizes: list[int | None], tail: int = 0, dtype=np.int64):
    """The prefix one by one, then blocks of ``sizes`` ticks in turn (None: all the rest), the
    last ``tail`` ticks one by one again."""
    _one_by_one(rec, frames.ids[: frames.prefix].tolist(), frames.datas[: frames.prefix])
    ends = frames.ends[1 : len(frames.ends) - tail].tolist()
    lo, t, i = frames.prefix, 0, 0
    while t < len(ends):
        size = sizes[i % len(sizes)]
        i += 1
        t = len(ends) if size is None else min(t + size, len(ends))
        hi = ends[t - 1]
        rec.record_ticks(frames.ids[lo:hi].astype(dtype), frames.payload[lo:hi])
        lo = hi
    _one_by_one(rec, frames.ids[lo:].tolist(), frames.datas[lo:])


def _blocks(out: Path, frames: Frames, sizes: list[int | None], tail: int = 0, **kw) -> dict:
    rec = _recorder(out, frames)
    _in_blocks(rec, frames, sizes, tail, **kw)
    return _result(rec, out)


def _assert_same(a: dict, b: dict) -> None:
    for key in ("can.log", "trace.csv", "totals", "state"):
        assert a[key] == b[key], key


@pytest.mark.parametrize("name", ["thesis-5.2-mrac-fast", "thesis-6.3-failure-mrac"])
def test_blocks_write_what_frames_one_by_one_write(tmp_path, runs, name):
    frames, run_log = runs[name]
    reference = _reference(tmp_path / "one", frames)
    # (the log read back and recorded again is the run's log: the canonical order)
    assert reference["can.log"] == run_log.read_bytes()
    assert reference["totals"]["missed_ticks"] == 0
    if name == "thesis-6.3-failure-mrac":
        assert 0x310 in frames.ids.tolist()
    cases = {
        "1": ([1], 0),
        "7": ([7], 0),
        "2048": ([2048], 0),
        "whole": ([None], 0),
        "mixed": ([3, 1, 2047, 500, 7], 3),
        "tail": ([2048], 25),
    }
    for case, (sizes, tail) in cases.items():
        dtype = np.int32 if case == "7" else np.uint16 if case == "mixed" else np.int64
        result = _blocks(tmp_path / case, frames, sizes, tail, dtype=dtype)
        _assert_same(result, reference)


@pytest.mark.parametrize("chunk_rows", [3, 333])
def test_chunk_boundaries_do_not_change_the_files(tmp_path, runs, monkeypatch, chunk_rows):
    frames, _ = runs["thesis-6.3-failure-mrac"]
    reference = _reference(tmp_path / "one", frames)
    monkeypatch.setattr(recorder_module, "CHUNK_ROWS", chunk_rows)
    _assert_same(_blocks(tmp_path / "ticks", frames, [700, 1, 2], tail=4), reference)
    _assert_same(_reference(tmp_path / "one-small", frames), reference)


def _shifted(frames: Frames, offset: int) -> Frames:
    """The run's ticks from ``offset`` on (their 16-bit numbers wrap), the CRCs made anew."""
    crc_start = {m.frame_id: data_id_crc_start(m.data_id) for m in Codec().messages}
    datas = []
    for frame_id, data in zip(frames.ids.tolist(), frames.datas, strict=True):
        if frame_id in (SENSORS, ACTUATOR):
            d = bytearray(data)
            tick = (d[2] + (d[3] << 8) + offset) % 65536
            d[2], d[3] = tick & 0xFF, tick >> 8
            d[0] = crc8(bytes(d[1:]), crc_start[frame_id])
            data = bytes(d)
        datas.append(data)
    shifted = Frames(frames.ids.tolist(), datas)
    shifted.commands = frames.commands
    return shifted


def test_blocks_across_the_16_bit_tick_wrap(tmp_path, runs):
    """A recorder that first hears tick 65000 (the ticks before it are written empty), then
    ticks past 65535: the full ticks go on."""
    frames = _shifted(runs["thesis-6.3-failure-mrac"][0], 65_000)
    reference = _reference(tmp_path / "one", frames)
    assert reference["totals"]["tick"] == 65_000 + len(frames.ends)
    assert reference["totals"]["missed_ticks"] == 0
    assert b"\n655.360000,65536," in reference["trace.csv"]
    for case, sizes, tail in (("7", [7], 2), ("whole", [None], 0), ("2048", [2048], 40)):
        _assert_same(_blocks(tmp_path / case, frames, sizes, tail), reference)


def _messed_up(frames: Frames) -> Frames:
    """Bad CRCs, a repeated frame and frames of an unknown ID, the ticks kept whole: at the end
    of the one-by-one prefix, in blocks and in the one-by-one tail."""
    ids, datas = frames.ids.tolist(), list(frames.datas)
    ends = frames.ends.tolist()

    def flip(i: int, byte: int, bit: int = 0) -> None:
        d = bytearray(datas[i])
        d[byte] ^= 1 << bit
        datas[i] = bytes(d)

    def in_tick(t: int, frame_id: int) -> int:
        lo = ends[t - 1] if t else 0
        return lo + ids[lo : ends[t]].index(frame_id)

    flip(in_tick(0, 0x200), 6)  # the prefix: EcuStatus with a bad CRC
    flip(in_tick(5, 0x210), 0)  # EcuTelemetry (multiplexed): the CRC itself
    flip(in_tick(5, 0x110), 7, 3)  # EcuActuator: a signal, the tick kept
    flip(in_tick(40, SENSORS), 5)  # PlantSensors: a missed tick for the tracker
    flip(in_tick(2100, 0x100), 1, 7)  # PlantSensors: the counter's upper bits, CRC bad
    flip(in_tick(len(ends) - 2, 0x110), 4)  # the tail: EcuActuator
    inserts = []  # (before index, ID, data): unknown IDs among the command node's frames
    for t in (3, 9, 9, 1500, len(ends) - 3):
        at = in_tick(t, SENSORS) + 1
        inserts.append((at, 0x555, bytes(range(t % 7, t % 7 + 8))))
    demand = ids.index(0x080, ends[9])
    inserts.append((demand + 1, 0x080, datas[demand]))  # a demand twice: REPEATED
    bad = bytearray(datas[demand])
    bad[0] ^= 0xFF
    for _ in range(2):  # and twice more, with a bad CRC
        inserts.append((demand + 1, 0x080, bytes(bad)))
    for at, frame_id, data in sorted(inserts, key=lambda x: x[0], reverse=True):
        ids.insert(at, frame_id)
        datas.insert(at, data)
    messed = Frames(ids, datas)
    messed.commands = frames.commands
    return messed


def test_bad_crcs_and_unknown_ids_in_blocks(tmp_path, runs):
    frames = _messed_up(runs["thesis-5.2-mrac-fast"][0])
    reference = _reference(tmp_path / "one", frames)
    totals = reference["totals"]
    assert sum(c.get("WRONGCRC", 0) for c in totals["e2e"].values()) == 8
    assert totals["e2e"]["Demand"]["REPEATED"] == 1
    assert totals["unknown_ids"] == {0x555: 5}
    assert totals["missed_ticks"] > 0
    for case, sizes in (("1", [1]), ("7", [7]), ("2048", [2048]), ("whole", [None])):
        _assert_same(_blocks(tmp_path / case, frames, sizes, tail=3), reference)
    # the frames with a bad CRC are logged but not decoded: the trace differs from the clean
    clean = _reference(tmp_path / "clean", runs["thesis-5.2-mrac-fast"][0])
    assert clean["trace.csv"] != reference["trace.csv"]


def test_the_state_after_every_block_is_that_after_the_same_frames(tmp_path, runs):
    """tick, latest_sensor_tick, frames, rows, E2E and the trackers as the command node reads
    them, after each block."""
    frames = _messed_up(runs["thesis-6.3-failure-mrac"][0])
    one, ticks = _recorder(tmp_path / "one", frames), _recorder(tmp_path / "ticks", frames)
    prefix = frames.prefix
    _one_by_one(one, frames.ids[:prefix].tolist(), frames.datas[:prefix])
    _one_by_one(ticks, frames.ids[:prefix].tolist(), frames.datas[:prefix])
    lo = prefix
    for hi in frames.ends[1:][6::7].tolist():
        ticks.record_ticks(frames.ids[lo:hi], frames.payload[lo:hi])
        _one_by_one(one, frames.ids[lo:hi].tolist(), frames.datas[lo:hi])
        assert _state(ticks) == _state(one)
        lo = hi
    for rec in (one, ticks):
        _one_by_one(rec, frames.ids[lo:].tolist(), frames.datas[lo:])
    _assert_same(_result(ticks, tmp_path / "ticks"), _result(one, tmp_path / "one"))


def _fresh(tmp_path: Path, frames: Frames, name: str) -> Recorder:
    rec = _recorder(tmp_path / name, frames)
    _one_by_one(rec, frames.ids[: frames.prefix].tolist(), frames.datas[: frames.prefix])
    return rec


def test_blocks_that_are_not_whole_ticks_in_order_are_refused(tmp_path, runs):
    frames, _ = runs["thesis-6.3-failure-mrac"]
    ids, payload, ends = frames.ids, frames.payload, frames.ends
    rec = _fresh(tmp_path, frames, "a")
    lo, hi = int(ends[0]), int(ends[10])  # ticks 1..10

    def refused(match: str, block_ids=None, block_payload=None) -> None:
        i = ids[lo:hi] if block_ids is None else block_ids
        p = payload[lo:hi] if block_payload is None else block_payload
        with pytest.raises(ValueError, match=match):
            rec.record_ticks(i, p)

    refused("the block does not end with an EcuActuator", ids[lo : hi - 1], payload[lo : hi - 1])
    skip = int(ends[1])  # from tick 2: tick 1 left out
    refused(
        r"frame \d+ of the block: PlantSensors tick 2, expected 1", ids[skip:hi], payload[skip:hi]
    )
    actuator = payload[lo:hi].copy()
    at = int(ends[3]) - 1 - lo  # tick 3's EcuActuator says 4
    actuator[at, 2] += 1
    refused(rf"frame {at} of the block: EcuActuator tick 4, expected 3", block_payload=actuator)
    order = ids[lo:hi].copy()
    status = int(np.flatnonzero(order == 0x200)[0])
    order[status], order[status - 1] = order[status - 1], order[status]
    refused(rf"frame {status} of the block: ID 0x\w+ after 0x200 in a tick, not in the", order)
    sensors = np.flatnonzero(ids[lo:hi] == SENSORS)[2]  # tick 3 without its PlantSensors
    keep = np.arange(hi - lo) != sensors
    refused(r"\(tick 3\): 0 PlantSensors, expected one", ids[lo:hi][keep], payload[lo:hi][keep])
    twice = np.insert(ids[lo:hi], sensors, SENSORS)
    refused(r"\(tick 3\): 2 PlantSensors", twice, np.insert(payload[lo:hi], sensors, 0, axis=0))
    # as many PlantSensors as ticks, but tick 4's in tick 3
    after = np.flatnonzero(ids[lo:hi] == SENSORS)[3]
    moved = np.insert(np.delete(ids[lo:hi], after), sensors, SENSORS)
    moved_payload = np.insert(np.delete(payload[lo:hi], after, 0), sensors, payload[lo + after], 0)
    refused(r"\(tick 3\): 2 PlantSensors", moved, moved_payload)
    refused("not a 1-D integer array", ids[lo:hi].astype(float))
    refused(r"payload is not a \(\d+, 8\) uint8 array", block_payload=payload[lo:hi, :7])
    refused("payload is not", block_payload=payload[lo:hi].astype(np.int16))
    refused("is not 11-bit", np.where(ids[lo:hi] == 0x080, 0x800, ids[lo:hi]))
    # the ticks right, as the bus has them, but not as this recorder reads them on (it cannot
    # happen when the ticks before were whole; a recorder told otherwise)
    unwrapped = rec._sensor_wrap.last
    rec._sensor_wrap.last = 40_000
    refused(r"PlantSensors tick 1 reads as 65537 after 40000, expected 1")
    rec._sensor_wrap.last = unwrapped
    # nothing was recorded: the right block now gives the files of the frames one by one
    _in_blocks_rest(rec, frames, lo)
    _assert_same(_result(rec, tmp_path / "a"), _reference(tmp_path / "one", frames))


def _in_blocks_rest(rec: Recorder, frames: Frames, lo: int) -> None:
    for hi in [*frames.ends[frames.ends > lo][99::100].tolist(), len(frames.ids)]:
        if hi > lo:
            rec.record_ticks(frames.ids[lo:hi], frames.payload[lo:hi])
            lo = hi


def test_a_block_after_frames_of_a_tick_not_yet_whole_is_refused(tmp_path, runs):
    frames, _ = runs["thesis-6.3-failure-mrac"]
    rec = _fresh(tmp_path, frames, "a")
    lo, hi = frames.prefix, int(frames.ends[1])
    ecu = lo + int(np.flatnonzero(np.isin(frames.ids[lo:], [0x200, 0x210, ACTUATOR]))[0])
    _one_by_one(rec, frames.ids[lo:ecu].tolist(), frames.datas[lo:ecu])  # tick 1 begun
    with pytest.raises(ValueError, match=r"frame\(s\) recorded one by one not yet written"):
        rec.record_ticks(frames.ids[ecu:], frames.payload[ecu:])
    _one_by_one(rec, frames.ids[ecu:hi].tolist(), frames.datas[ecu:hi])
    _in_blocks_rest(rec, frames, hi)
    _assert_same(_result(rec, tmp_path / "a"), _reference(tmp_path / "one", frames))
    (tmp_path / "wall").mkdir()
    wall = Recorder(tmp_path / "wall", Codec(), PERIOD_S, wall_clock=True)
    with pytest.raises(ValueError, match="not in real time"):
        wall.record_ticks(frames.ids[: frames.prefix], frames.payload[: frames.prefix])
    wall.close()
    with pytest.raises(ValueError, match="closed"):
        rec.record_ticks(frames.ids[:0], frames.payload[:0])


def test_ctrl_c_while_a_block_is_written_keeps_whole_ticks(tmp_path, runs, monkeypatch):
    """The interrupt waits until the chunk is on disk; the block's ticks until then are
    recorded, the rest not; close() writes them: the files of those ticks one by one."""
    frames, _ = runs["thesis-5.2-mrac-fast"]
    monkeypatch.setattr(recorder_module, "CHUNK_ROWS", 500)
    original = TraceWriter.write_rows
    calls = []

    def write_rows(self, *args):
        calls.append(True)
        if len(calls) == 2:  # the second chunk, the block's first
            signal.raise_signal(signal.SIGINT)
        original(self, *args)

    monkeypatch.setattr(TraceWriter, "write_rows", write_rows)
    rec = _fresh(tmp_path, frames, "a")
    lo, hi = frames.prefix, int(frames.ends[400])
    rec.record_ticks(frames.ids[lo:hi], frames.payload[lo:hi])  # ticks 1..400: no chunk yet
    with pytest.raises(KeyboardInterrupt):  # chunks at ticks 499 and 999, interrupted at 999
        rec.record_ticks(frames.ids[hi:], frames.payload[hi:])
    assert rec.tick == 1000 and len(calls) == 2
    monkeypatch.setattr(TraceWriter, "write_rows", original)
    cut = int(frames.ends[999])
    assert rec.frames == cut
    a = _result(rec, tmp_path / "a")
    rec = _recorder(tmp_path / "one", frames)
    _one_by_one(rec, frames.ids[:cut].tolist(), frames.datas[:cut])
    _assert_same(a, _result(rec, tmp_path / "one"))


def test_in_order_ticks_of_a_block_are_those_of_its_frames():
    rng = np.random.default_rng(2)
    ticks = np.cumsum(rng.choice([1, 1, 1, 0, 2, -1, 30_000], 3000)) % 65536
    ids = np.where(rng.random(3000) < 0.7, SENSORS, rng.choice([ACTUATOR, 0x200, 0x080], 3000))
    payload = rng.integers(0, 256, (3000, 8)).astype(np.uint8)
    payload[:, 2], payload[:, 3] = ticks & 0xFF, ticks >> 8
    one, many = InOrderTicks(), InOrderTicks()
    for frame_id, data in zip(ids.tolist(), payload, strict=True):
        one.track(frame_id, bytes(data))
    for lo in range(0, 3000, 250):
        many.track_many(ids[lo : lo + 250], payload[lo : lo + 250])
    assert (many.tick, many.latest_sensor_tick) == (one.tick, one.latest_sensor_tick)
    assert many._sensor_wrap.last == one._sensor_wrap.last
    assert one.latest_sensor_tick > 65536  # (it wrapped)


def _process_blocks(out: Path, frames: Frames, sizes: list[int | None], tail: int) -> dict:
    rec = RecorderProcess().open(out, PERIOD_S, commands=frames.commands)
    _in_blocks(rec, frames, sizes, tail)
    view = (rec.tick, rec.latest_sensor_tick, rec.frames)
    rec.close()
    return {
        "view": view,
        "totals": rec.totals(),
        "can.log": (out / "can.log").read_bytes(),
        "trace.csv": (out / "trace.csv").read_bytes(),
    }


def test_the_recorder_process_records_blocks_as_the_recorder(tmp_path, runs):
    frames = _messed_up(runs["thesis-6.3-failure-mrac"][0])
    reference = _reference(tmp_path / "one", frames)
    state = reference["state"]
    for case, sizes, tail in (("7", [7, 1], 2), ("whole", [None], 0)):
        (tmp_path / case).mkdir()
        result = _process_blocks(tmp_path / case, frames, sizes, tail)
        assert result["view"] == (state["tick"], state["latest_sensor_tick"], state["frames"])
        for key in ("can.log", "trace.csv", "totals"):
            assert result[key] == reference[key], key


def test_the_recorder_process_refuses_a_bad_block_and_reports_a_dead_child(tmp_path, runs):
    frames, _ = runs["thesis-6.3-failure-mrac"]
    rec = RecorderProcess().open(tmp_path, PERIOD_S)
    _one_by_one(rec, frames.ids[: frames.prefix].tolist(), frames.datas[: frames.prefix])
    lo = frames.prefix
    with pytest.raises(ValueError, match="does not end with an EcuActuator"):
        rec.record_ticks(frames.ids[lo:-1], frames.payload[lo:-1])
    assert (rec.tick, rec.frames) == (1, frames.prefix)  # nothing sent
    hi = int(frames.ends[10])
    rec.record_ticks(frames.ids[lo:hi], frames.payload[lo:hi])
    deadline = time.monotonic() + 30
    while not (tmp_path / "trace.csv").exists():  # the child's recorder is up
        assert time.monotonic() < deadline
        time.sleep(0.01)
    os.kill(rec._child.pid, signal.SIGKILL)
    rec._child.wait()
    with pytest.raises(RecorderFailed, match="exited with code -9"):
        rec.record_ticks(frames.ids[hi:], frames.payload[hi:])
    with pytest.raises(RecorderFailed):
        rec.close()


def test_a_block_the_recorder_process_cannot_take_ends_it(tmp_path, runs, capfd):
    """Frames of a tick begun one by one, then the tick whole: the child refuses the block and
    exits; the run learns it at close."""
    frames, _ = runs["thesis-6.3-failure-mrac"]
    rec = RecorderProcess().open(tmp_path, PERIOD_S)
    lo = frames.prefix
    _one_by_one(rec, frames.ids[: lo + 1].tolist(), frames.datas[: lo + 1])
    rec.record_ticks(frames.ids[lo:], frames.payload[lo:])
    with pytest.raises(RecorderFailed, match="exited with code 1"):
        rec.close()
    assert "not yet written as whole ticks" in capfd.readouterr().err
