"""Frame lengths with stuff bits against a plain bit-by-bit reference."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.busload import CRC15_POLY, BitCounter, bus_load_pct, frames_bits


def _reference_bits(frame_id: int, data: bytes) -> int:
    """The frame built bit by bit, CRC shifted bit by bit, stuffing done by inserting bits."""
    bits = [0] + [int(b) for b in f"{frame_id:011b}"] + [0, 0, 0]
    bits += [int(b) for b in f"{len(data):04b}"]
    for byte in data:
        bits += [int(b) for b in f"{byte:08b}"]
    crc = 0
    for bit in bits:
        feedback = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= CRC15_POLY
    bits += [int(b) for b in f"{crc:015b}"]
    stuffed, run, last = [], 0, None
    for bit in bits:
        stuffed.append(bit)
        run = run + 1 if bit == last else 1
        last = bit
        if run == 5:
            stuffed.append(1 - bit)
            last, run = 1 - bit, 1
    return len(stuffed) + 13


frames = st.lists(
    st.tuples(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8)), min_size=1, max_size=40
)


@settings(max_examples=200)
@given(frames)
def test_counter_matches_the_bitwise_reference(batch):
    counter = BitCounter(batch=7)
    for frame_id, data in batch:
        counter.add(frame_id, data)
    assert counter.flush() == sum(_reference_bits(i, d) for i, d in batch)
    assert counter.frames == len(batch)


@given(st.integers(0, 0x7FF), st.binary(min_size=8, max_size=8))
def test_eight_byte_frames_are_between_111_and_135_bits(frame_id, data):
    bits = frames_bits(np.array([frame_id]), 8, np.frombuffer(data, np.uint8).reshape(1, 8))
    assert 111 <= int(bits[0]) <= 135  # 111 unstuffed; stuffing adds at most 24


def test_known_stuffing_cases():
    # all-zero payload: long runs of zeros; all-ones: long runs of ones
    zeros = frames_bits(np.array([0]), 8, np.zeros((1, 8), np.uint8))[0]
    assert zeros == _reference_bits(0, bytes(8))
    assert zeros > 125


def test_bad_frames_and_load_percent():
    with pytest.raises(ValueError, match="11 bits"):
        frames_bits(np.array([0x800]), 0, np.zeros((1, 0), np.uint8))
    assert bus_load_pct(500_000, 1.0) == 100.0
    assert bus_load_pct(4000 * 125, 2.0) == 50.0
    assert bus_load_pct(10, 0) == 0.0
