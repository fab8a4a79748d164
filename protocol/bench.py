"""Codec figures: encode and decode time per frame against cantools, and allocation growth."""

from __future__ import annotations

import sys
import time

from protocol.codec import Codec


def _per_call_us(fn, n: int) -> float:
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


TARGET_TEXT = {
    "faster_than_cantools": "encode and decode faster than cantools",
    "no_allocation_per_frame": "under 1 allocated block per 1,000 frames encoded and decoded",
}


def run(quick: bool = False) -> dict:
    n = 2_000 if quick else 20_000
    codec = Codec()
    db = codec.database
    sensors = codec["PlantSensors"]
    raws = (1234, 100_500, 10_300)
    phys = {
        "Sensors_CRC": 0,
        "Sensors_Counter": 0,
        "SensorTick": 1234,
        "ShaftSpeed": 100_500,
        "EGT": 1030.0,
    }
    out = [0, 0, 0]
    sensors.pack_raw(raws)
    frame = bytes(sensors.data)
    cantools_msg = db.get_message_by_frame_id(sensors.frame_id)

    figures = {
        "message": sensors.name,
        "codec_encode_us": _per_call_us(lambda: sensors.pack_raw(raws), n),
        "codec_decode_us": _per_call_us(lambda: sensors.unpack_raw(frame, out), n),
        "cantools_encode_us": _per_call_us(lambda: cantools_msg.encode(phys), n),
        "cantools_decode_us": _per_call_us(lambda: cantools_msg.decode(frame), n),
    }
    # cantools computes no CRC: the codec's encode includes the E2E counter and CRC-8.
    figures["encode_speedup"] = figures["cantools_encode_us"] / figures["codec_encode_us"]
    figures["decode_speedup"] = figures["cantools_decode_us"] / figures["codec_decode_us"]

    for _ in range(1000):  # warm up
        sensors.pack_raw(raws)
        sensors.unpack_raw(sensors.data, out)
    before = sys.getallocatedblocks()
    for _ in range(n):
        sensors.pack_raw(raws)
        sensors.unpack_raw(sensors.data, out)
    figures["alloc_blocks_per_1k_frames"] = (sys.getallocatedblocks() - before) * 1000 / n
    out = {k: round(v, 3) if isinstance(v, float) else v for k, v in figures.items()}
    out["targets_met"] = {
        "faster_than_cantools": figures["encode_speedup"] > 1 and figures["decode_speedup"] > 1,
        "no_allocation_per_frame": figures["alloc_blocks_per_1k_frames"] < 1,
    }
    return out
