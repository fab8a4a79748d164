"""The recorder: candump log readable by python-can and cantools, one trace row per tick."""

import can
import numpy as np
import pytest

from protocol.codec import Codec
from sil.metrics import load_trace, summarize, tracking_rms_pct
from sil.recorder import Recorder


def _tick(
    codec: Codec, rec: Recorder, k: int, *, rpm: int, ref: float, owner: int = 0, fault: int = 0
) -> None:
    for name, values in (
        ("PlantTruthB", [0.008, 170.0, rpm + 50]),
        ("PlantSensors", [k, rpm, 1030.0]),
        ("EcuStatus", [2, fault, 100.0, owner, ref]),
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


def test_frames_arriving_out_of_order_are_logged_in_canonical_order(tmp_path):
    """The ECU's answer may reach the recorder before the frame it answers: same log anyway."""
    codec = Codec()
    frames = {}
    for k in range(3):
        for name, values in (
            ("PlantSensors", [k, 100_000, 1000.0]),
            ("EcuStatus", [2, 0, 100.0, 0, 90.0]),
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
        demand = Codec()["Demand"]
        for frame_id, data in sequence:
            rec.record(frame_id, data)
            if frame_id == 0x100:  # the command node answers each sensor frame at once
                demand.pack([1, 0, 90.0, 0.0, data[2] + 5])
                rec.record(demand.frame_id, demand.data)
        rec.close()
        assert rec.tick == 3 and rec.missed_ticks == 0
        logs.append((tmp_path / name / "can.log").read_text())
    assert logs[0] == logs[1]
    assert logs[0].count("vcan0 080#") == 3  # every demand kept, each in its tick
