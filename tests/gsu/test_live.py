"""The page's live values from the contract's frames: frames packed by the nodes' own codec
(protocol.codec), decoded by the page with cantools, give back what was packed; a fault bit
that comes up is logged once with the values of that moment (the limit loops' information bits
are not faults); the chart keeps 10 samples a
second; a recording keeps every frame from its start, stamped with the time it came."""

from __future__ import annotations

import can
import pytest

from ecu import faults
from protocol.codec import Codec
from sil.console.gsu.live import HISTORY_HZ, Live


def _frame(codec: Codec, name: str, values: dict[str, float]) -> can.Message:
    message = codec[name]
    message.pack([values[s] for s in message.signal_names])
    return can.Message(arbitration_id=message.frame_id, data=bytes(message.data),
                       is_extended_id=False)  # fmt: skip


STATUS = {
    "EcuMode": 2, "FaultWord": 0, "PumpHealth": 98.5, "LoopOwner": 1, "ReferenceSpeed": 71.25,
    "SensorsValid": 1,
}  # fmt: skip


def test_frames_decode_to_the_values_packed() -> None:
    codec, live = Codec(), Live()
    live.feed(
        _frame(codec, "PlantSensors", {"SensorTick": 7, "ShaftSpeed": 80_000, "EGT": 905.3}), 1.0
    )
    live.feed(_frame(codec, "EcuStatus", STATUS), 1.01)
    s = live.snapshot(1.02)
    assert s["speed_rpm"] == 80_000 and s["speed_pct"] == pytest.approx(80_000 / 1125)
    assert s["egt_k"] == pytest.approx(905.3)
    assert s["state"] == "RUN" and s["owner"] == "EGT_LIMIT"
    assert s["speed_ref_pct"] == pytest.approx(71.25)
    assert s["pump_health_pct"] == pytest.approx(98.5)
    assert s["frame_s"] == 1.0 and not s["ecu_silent"]
    assert live.snapshot(1.01 + 0.6)["ecu_silent"]  # no status frame for 0.6 s


def test_a_fault_is_logged_once_with_its_snapshot() -> None:
    codec, live = Codec(), Live()
    live.feed(
        _frame(codec, "PlantSensors", {"SensorTick": 1, "ShaftSpeed": 90_000, "EGT": 1010}), 1.0
    )
    word = faults.EGT_OVERTEMP | faults.LIMITER_ACTIVE
    for k in range(5):
        live.feed(_frame(codec, "EcuStatus", {**STATUS, "FaultWord": word}), 1.1 + k * 0.05)
    live.feed(_frame(codec, "EcuStatus", {**STATUS, "FaultWord": word | faults.OVERSPEED}), 2.0)
    log = live.faults_seen()
    assert [e["bits"] for e in log] == [["EGT_OVERTEMP"], ["OVERSPEED"]]  # (no information bit)
    assert log[0]["snapshot"]["egt_k"] == pytest.approx(1010) and log[0]["wall_s"] == 1.1
    assert live.snapshot(2.0)["faults"] == ["EGT_OVERTEMP", "OVERSPEED", "LIMITER_ACTIVE"]


def test_the_chart_samples_at_ten_hertz_and_a_recording_keeps_every_frame() -> None:
    codec, live = Codec(), Live()
    assert live.stop_recording() is None
    frames = []
    for k in range(300):  # 3 s of sensor frames at 100 Hz
        frame = _frame(codec, "PlantSensors", {"SensorTick": k, "ShaftSpeed": 1000 * k, "EGT": 300})
        frames.append(frame)
        live.feed(frame, 10.0 + k * 0.01)
        if k == 100:
            assert live.start_recording() and not live.start_recording()
    chart = live.chart()
    assert len(chart) == pytest.approx(3 * HISTORY_HZ, abs=1)
    assert all(0.099 <= b[0] - a[0] <= 0.111 for a, b in zip(chart, chart[1:], strict=False))
    kept = live.stop_recording()
    assert kept == frames[101:]
    assert [m.timestamp for m in kept] == pytest.approx([10.0 + k * 0.01 for k in range(101, 300)])


def test_a_start_aborted_is_logged_with_its_reason() -> None:
    codec, live = Codec(), Live()
    starter = {"IgniterOn": 0, "StarterTick": 0, "StarterDuty": 40.0, "SequencerState": 1}
    live.feed(_frame(codec, "EcuStarter", {**starter, "AbortReason": 6}), 1.0)  # the last start's
    live.feed(_frame(codec, "EcuStarter", {**starter, "AbortReason": 0}), 2.0)
    live.feed(_frame(codec, "EcuStarter", {**starter, "AbortReason": 1}), 3.0)
    live.feed(_frame(codec, "EcuStarter", {**starter, "AbortReason": 1}), 3.01)
    assert [(e["wall_s"], e["bits"]) for e in live.faults_seen()] == [
        (3.0, ["START_ABORT_IGNITION_TIMEOUT"])
    ]
