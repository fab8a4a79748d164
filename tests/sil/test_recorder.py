"""The recorder: candump log readable by python-can and cantools, one trace row per tick."""

import random
import signal

import can
import numpy as np
import pytest

import sil.record.recorder as recorder_module
from protocol.busload import frames_bits, frames_bits_bytewise
from protocol.codec import Codec
from protocol.e2e import crc8, crc8_rows, data_id_crc_start
from sil.analysis.metrics import load_trace, summarize, tracking_rms_pct
from sil.record.canlog import CandumpWriter, fixed6
from sil.record.recorder import Recorder
from sil.record.trace_writer import TraceWriter


def _tick(
    codec: Codec, rec: Recorder, k: int, *, rpm: int, ref: float, owner: int = 0, fault: int = 0
) -> None:
    for name, values in (
        ("PlantTruthB", [0.008, 170.0, rpm + 50]),
        ("PlantSensors", [k, rpm, 1030.0]),
        ("EcuStatus", [2, fault, 100.0, owner, ref, 1]),
        ("EcuTelemetry", [2, 4.8 + k * 0.001]),
        ("EcuActuator", [1, 2, k, 50.0, 6.0]),
    ):
        message = codec[name]
        message.pack(values)
        rec.record(message.frame_id, message.data)


def test_log_and_trace(tmp_path):
    codec, rx = Codec(), Codec()
    rec = Recorder(tmp_path, rx, period_s=0.01, commands=np.full(20, 90.0))
    for k in range(20):
        _tick(
            codec,
            rec,
            k,
            rpm=100_000 + k,
            ref=89.0,
            owner=1 if k >= 15 else 0,
            fault=(1 << 14) if k == 10 else 0,
        )
    rec.close()

    frames = list(can.CanutilsLogReader(str(tmp_path / "can.log")))
    assert len(frames) == 100 == rec.frames
    assert frames[0].timestamp == 0.0 and frames[5].timestamp == pytest.approx(0.01)
    assert frames[1].arbitration_id == 0x100 and frames[1].timestamp == pytest.approx(10e-6)
    db = rx.database
    assert db.decode_message(0x100, frames[6].data)["SensorTick"] == 1
    assert rec.missed_ticks == 0
    assert all(c == {"OK": 20} for c in rec.e2e.values())

    trace = load_trace(tmp_path / "trace.csv")
    assert len(trace["time"]) == 20
    assert trace["speed_true"][3] == pytest.approx(100.0 * 100_053 / 112_500)
    assert trace["Est_Lambda"][-1] == pytest.approx(4.819, abs=1e-6)
    assert tracking_rms_pct(trace) == pytest.approx(
        np.sqrt(np.mean((100 * (100_050 + np.arange(20)) / 112_500 - 89.0) ** 2)), rel=1e-5
    )
    summary = summarize(trace, 0.01, {1 << 14: "LIMITER_ACTIVE"})
    assert summary["egt_limit_time_s"] == pytest.approx(0.05)
    assert summary["faults"] == [{"time_s": 0.1, "fault": "LIMITER_ACTIVE"}]
    assert summary["max_egt_K"] == pytest.approx(1030.0)


def test_lost_ticks_bad_crc_and_unknown_ids_are_counted(tmp_path):
    codec, rx = Codec(), Codec()
    rec = Recorder(tmp_path, rx, period_s=0.01)
    for k in (0, 1, 4):
        _tick(codec, rec, k, rpm=100_000, ref=90.0)
    sensors = codec["PlantSensors"]
    sensors.pack([5, 100_000, 1000.0])
    bad = bytearray(sensors.data)
    bad[3] ^= 1
    rec.record(0x100, bad)
    rec.record(0x555, bytes(8))
    rec.close()
    assert rec.sensor_ticks.missing == 2 and rec.actuator_ticks.missing == 2
    assert rec.missed_ticks == 4
    assert rec.e2e["PlantSensors"]["WRONGCRC"] == 1
    assert rec.unknown_ids[0x555] == 1
    assert rec.frames == 17  # every frame is logged, good or bad
    assert len(list(can.CanutilsLogReader(str(tmp_path / "can.log")))) == 17


def test_a_known_id_of_the_wrong_length_is_counted_apart_from_unknown_ids(tmp_path):
    codec = Codec()
    rec = Recorder(tmp_path, Codec(), period_s=0.01)
    _tick(codec, rec, 0, rpm=100_000, ref=90.0)
    rec.record(0x100, bytes(5))  # PlantSensors is 8 bytes long
    rec.record(0x555, bytes(8))
    rec.close()
    assert rec.wrong_length == {0x100: 1}
    assert rec.unknown_ids == {0x555: 1}
    assert rec.totals()["wrong_length"] == {0x100: 1}


def test_frames_arriving_out_of_order_are_logged_in_canonical_order(tmp_path):
    """The ECU's answer may reach the recorder before the frame it answers: same log anyway."""
    codec = Codec()
    frames = {}
    for k in range(3):
        for name, values in (
            ("PlantSensors", [k, 100_000, 1000.0]),
            ("EcuStatus", [2, 0, 100.0, 0, 90.0, 1]),
            ("EcuActuator", [1, 2, k, 50.0, 6.0]),
        ):
            m = codec[name]
            m.pack(values)
            frames[(name, k)] = (m.frame_id, bytes(m.data))
    in_order = [
        frames[(n, k)] for k in range(3) for n in ("PlantSensors", "EcuStatus", "EcuActuator")
    ]
    # each sender's frames in its own order, but the ECU's tick-1 answer before PlantSensors(1)
    shuffled = [
        frames[("PlantSensors", 0)],
        frames[("EcuStatus", 0)],
        frames[("EcuActuator", 0)],
        frames[("EcuStatus", 1)],
        frames[("EcuActuator", 1)],
        frames[("PlantSensors", 1)],
        frames[("PlantSensors", 2)],
        frames[("EcuStatus", 2)],
        frames[("EcuActuator", 2)],
    ]
    logs = []
    for name, sequence in (("a", in_order), ("b", shuffled)):
        (tmp_path / name).mkdir()
        rec = Recorder(tmp_path / name, Codec(), period_s=0.01)
        demand, fault = Codec()["Demand"], Codec()["FaultInject"]
        for frame_id, data in sequence:
            rec.record(frame_id, data)
            if frame_id == 0x100:  # the command node answers each sensor frame at once
                if data[2] == 1:  # a fault injection first, then the demand: two frames
                    fault.pack([1, 6, 0.5])
                    rec.record(fault.frame_id, fault.data)
                demand.pack([1, 0, 90.0, 0.0, data[2] + 5])
                rec.record(demand.frame_id, demand.data)
        rec.close()
        assert rec.tick == 3 and rec.missed_ticks == 0
        logs.append((tmp_path / name / "can.log").read_text())
    assert logs[0] == logs[1]
    assert logs[0].count("vcan0 080#") == 3  # every demand kept, each in its tick
    lines = logs[0].splitlines()
    assert [line.split()[2][:3] for line in lines[4:8]] == ["100", "310", "080", "200"]


def _messy_stream(seed: int) -> list[tuple[int, bytes]]:
    """Ticks with frames lost, duplicated, corrupted, cut short, unknown and out of order."""
    rng = random.Random(seed)
    codec = Codec()
    frames: list[tuple[int, bytes]] = []
    demand = codec["Demand"]
    demand.pack([1, 0, 90.0, 0.0, 0])
    frames.append((demand.frame_id, bytes(demand.data)))
    for k in range(rng.randint(30, 200)):
        plant, command, ecu = [], [], []
        for name, values, out in (
            ("PlantTruthB", [0.008, 150.0, 100_000 + rng.randint(0, 999)], plant),
            ("PlantAnalog", [k, 22.0 + rng.random(), 2.1], plant),
            ("PlantSensors", [k, 100_000 + rng.randint(0, 999), 1000 + rng.random() * 50], plant),
            ("Demand", [1, 0, rng.uniform(70, 100), 0.0, (k + 5) % 65536], command),
            ("EcuStatus", [2, rng.choice([0, 1 << 14]), 100.0, rng.randint(0, 2), 89.0, 1], ecu),
            ("EcuTelemetry", [rng.randint(0, 12), rng.uniform(-10, 10)], ecu),
            ("EcuActuator", [1, 2, k, rng.uniform(0, 100), 6.0], ecu),
        ):
            last = name in ("PlantSensors", "EcuActuator")
            if not last and rng.random() < 0.3:
                continue
            message = codec[name]
            message.pack(values)
            data = bytes(message.data)
            r = rng.random()
            if r < 0.05:  # a flipped bit: WRONGCRC, logged but never decoded
                flipped = bytearray(data)
                flipped[rng.randrange(8)] ^= 1 << rng.randrange(8)
                data = bytes(flipped)
            elif r < 0.07 and not last:
                data = data[: rng.randrange(8)]  # cut short: an unknown frame
            elif r < 0.09 and not last:
                continue  # lost
            out.append((message.frame_id, data))
            if rng.random() < 0.03:
                out.append((message.frame_id, data))  # duplicated
        if rng.random() < 0.05:
            plant.append((0x555, bytes(8)))
        senders = [plant, command, ecu]
        while any(senders):  # each sender's own order kept, interleaved at random
            frames.append(rng.choice([s for s in senders if s]).pop(0))
    return frames


def _record_all(out_dir, frames, *, wall_clock: bool = False) -> dict:
    out_dir.mkdir()
    rec = Recorder(
        out_dir, Codec(), period_s=0.01, commands=np.linspace(70, 100, 150), wall_clock=wall_clock
    )
    for i, (frame_id, data) in enumerate(frames):
        rec.record(frame_id, bytearray(data), i * 0.0037)
    rec.close()
    return {
        "log": (out_dir / "can.log").read_bytes(),
        "trace": (out_dir / "trace.csv").read_bytes(),
        "e2e": {m: dict(c) for m, c in rec.e2e.items()},
        "unknown": list(rec.unknown_ids.items()),
        "missed": rec.missed_ticks,
        "frames": rec.frames,
        "bits": rec.bits.flush(),
        "tick": rec.tick,
    }


@pytest.mark.parametrize("seed", range(6))
def test_bulk_writes_do_not_depend_on_the_chunk_size(tmp_path, monkeypatch, seed):
    """Frames are decoded and written per chunk: any chunk size gives the same files."""
    frames = _messy_stream(seed)
    wall_clock = seed == 5
    results = []
    for rows, heard in ((1, 3), (7, 50), (512, 8192)):
        monkeypatch.setattr(recorder_module, "CHUNK_ROWS", rows)
        monkeypatch.setattr(recorder_module, "_CHUNK_FRAMES", heard)
        results.append(_record_all(tmp_path / f"c{rows}", frames, wall_clock=wall_clock))
    assert results[0] == results[1] == results[2]
    assert sum(c.get("WRONGCRC", 0) for c in results[0]["e2e"].values()) > 0
    assert results[0]["unknown"]


def test_a_corrupted_frame_is_logged_but_never_decoded(tmp_path):
    codec, rx = Codec(), Codec()
    rec = Recorder(tmp_path, rx, period_s=0.01)
    _tick(codec, rec, 0, rpm=100_000, ref=90.0)
    status = codec["EcuStatus"]
    status.pack([2, 0, 100.0, 0, 80.0, 1])
    bad = bytearray(status.data)
    bad[7] ^= 0x10  # ReferenceSpeed changed, CRC not: WRONGCRC
    sensors, actuator = codec["PlantSensors"], codec["EcuActuator"]
    sensors.pack([1, 100_000, 1000.0])
    rec.record(sensors.frame_id, sensors.data)
    rec.record(status.frame_id, bad)
    actuator.pack([1, 2, 1, 50.0, 6.0])
    rec.record(actuator.frame_id, actuator.data)
    rec.close()
    trace = load_trace(tmp_path / "trace.csv")
    assert list(trace["ReferenceSpeed"]) == [90.0, 90.0]
    assert rec.e2e["EcuStatus"] == {"OK": 1, "WRONGCRC": 1}
    assert (tmp_path / "can.log").read_text().count(f"200#{bytes(bad).hex().upper()}") == 1


def test_bulk_candump_lines_equal_line_by_line(tmp_path):
    rng = np.random.default_rng(7)
    n = 300
    ts = np.concatenate([rng.uniform(0, 1e5, n - 3), [0.0, 0.0000005, 123456.5]])
    ids = rng.integers(0, 0x800, n)
    ids[:4] = [0, 0xF, 0x7FF, 0x1FFFFFFF]
    lengths = rng.integers(0, 9, n)
    payload = rng.integers(0, 256, (n, 8)).astype(np.uint8)
    payload[np.arange(8)[None, :] >= lengths[:, None]] = 0
    one, many = CandumpWriter(tmp_path / "one.log"), CandumpWriter(tmp_path / "many.log")
    for t, i, d, k in zip(ts.tolist(), ids.tolist(), payload, lengths.tolist(), strict=True):
        one.write(t, i, bytes(d[:k]))
    many.write_many(ts, ids, payload, lengths)
    one.close()
    many.close()
    assert (tmp_path / "one.log").read_bytes() == (tmp_path / "many.log").read_bytes()


def test_vectorised_crc_and_bit_counts_equal_the_reference():
    rng = np.random.default_rng(3)
    data = rng.integers(0, 256, (500, 7)).astype(np.uint8)
    for data_id in (1, 0x100, 0xBEEF):
        start = data_id_crc_start(data_id)
        assert crc8_rows(data, start).tolist() == [crc8(bytes(r), start) for r in data]
    for dlc in range(9):
        ids = rng.integers(0, 0x800, 2000)
        frames = rng.integers(0, 256, (2000, 8)).astype(np.uint8)
        frames[:500] = 0  # long runs: many stuff bits
        frames[500:1000] = 0xFF
        ids[:700] = rng.choice([0, 0x7FF], 700)
        assert (frames_bits(ids, dlc, frames) == frames_bits_bytewise(ids, dlc, frames)).all()


def test_ctrl_c_while_a_chunk_is_written_leaves_no_gap(tmp_path, monkeypatch):
    """The interrupt waits until the chunk is on disk; close() then writes the rest."""
    monkeypatch.setattr(recorder_module, "CHUNK_ROWS", 5)
    frames = _messy_stream(11)
    original = TraceWriter.write_rows
    interrupted = []

    def write_rows(self, *args):
        if not interrupted:  # after can.log, before trace.csv
            interrupted.append(True)
            signal.raise_signal(signal.SIGINT)
        original(self, *args)

    monkeypatch.setattr(TraceWriter, "write_rows", write_rows)
    (tmp_path / "a").mkdir()
    rec = Recorder(tmp_path / "a", Codec(), period_s=0.01)
    heard = 0
    with pytest.raises(KeyboardInterrupt):
        for frame_id, data in frames:
            heard += 1
            rec.record(frame_id, data)
    rec.close()
    assert interrupted and 0 < heard < len(frames)
    monkeypatch.setattr(TraceWriter, "write_rows", original)
    (tmp_path / "b").mkdir()
    reference = Recorder(tmp_path / "b", Codec(), period_s=0.01)
    for frame_id, data in frames[:heard]:
        reference.record(frame_id, data)
    reference.close()
    for name in ("can.log", "trace.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_timestamps_formatted_without_percent_equal_percent_6f():
    rng = np.random.default_rng(5)
    values = np.concatenate(
        [
            rng.uniform(0, 1e6, 20_000),
            rng.uniform(0, 1e-3, 2_000),
            np.arange(30_000) / 640,  # ties at half a microsecond
            np.arange(30_000) * 0.01 + np.arange(30_000) % 5 * 1e-5,
            [0.0, 1e-7, 0.9999996, 999_999.9999994],
        ]
    )
    scaled = values * 1e6
    near_tie = np.abs(scaled - np.floor(scaled) - 0.5) < 0.01
    assert fixed6(values) is None and fixed6(values[near_tie][:1]) is None
    sure = values[~near_tie]
    text = [row[row != 0].tobytes().decode() for row in fixed6(sure)]
    assert text == [f"{v:.6f}" for v in sure.tolist()]  # as CandumpWriter.write
