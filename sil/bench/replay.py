"""`sil bench replay`: log read-and-decode rate, and real-time playback timing error."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from protocol.bus import open_bus
from protocol.codec import Codec
from sil.record import replay
from sil.record.canlog import CandumpWriter, read_frames


def _write_log(path: Path, frames: int, rate_hz: float) -> None:
    codec = Codec()
    names = ("PlantSensors", "EcuActuator", "EcuStatus", "PlantTruthA")
    values = {
        "PlantSensors": [0, 100_000, 1000.0],
        "EcuActuator": [1, 2, 0, 40.0, 5.0],
        "EcuStatus": [2, 0, 100.0, 0, 90.0, 1],
        "PlantTruthA": [0, 0, 0, 0, 3e5, 1.6e5, 1159],
    }
    writer = CandumpWriter(path)
    for i in range(frames):
        m = codec[names[i % 4]]
        m.pack(values[m.name])
        writer.write(i / rate_hz, m.frame_id, m.data)
    writer.close()


def run(quick: bool = False) -> dict:
    frames = 100_000 if quick else 1_000_000
    play_s = 5.0 if quick else 60.0
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "bench.log"
        _write_log(log, frames, 1000.0)
        decoder = replay.Decoder()
        t0 = time.perf_counter()
        for msg in read_frames(log):
            decoder.decode(msg)
        read_s = time.perf_counter() - t0

        short = Path(tmp) / "play.log"
        _write_log(short, int(play_s * 1000), 1000.0)
        with open_bus("virtual:sil_bench_replay") as bus:
            report = replay.play(short, bus).as_dict()
    return {
        "log_frames": frames,
        "read_decode_frames_per_s": round(frames / read_s),
        "playback_rate_hz": 1000,
        "playback_s": play_s,
        "playback_sent": report["sent"],
        "timing_error_p50_ms": round(report["timing_error_ms"]["p50"], 4),
        "timing_error_p99_ms": round(report["timing_error_ms"]["p99"], 4),
        "timing_error_max_ms": round(report["timing_error_ms"]["max"], 4),
    }
