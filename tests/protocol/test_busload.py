"""Frame length with stuff bits against a plain bit-by-bit reference."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.busload import CRC15_POLY, bus_load_pct, crc15, frame_bits, stuff_bits


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


@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_frame_bits_match_the_bitwise_reference(frame_id, data):
    assert frame_bits(frame_id, data) == _reference_bits(frame_id, data)


@given(st.integers(0, 0x7FF), st.binary(min_size=8, max_size=8))
def test_eight_byte_frames_are_between_111_and_135_bits(frame_id, data):
    # 111 unstuffed bits; stuffing of the 98 stuffable bits adds at most 24
    assert 111 <= frame_bits(frame_id, data) <= 135


def test_crc15_remainder_property():
    data = bytes([0x12, 0x34, 0x56])
    crc = crc15(data)
    # the message followed by its CRC (aligned on bits) leaves a zero remainder
    value = (int.from_bytes(data, "big") << 15) | crc
    assert crc15(value.to_bytes(6, "big")) == 0


def _stuff(text: str) -> int:
    return stuff_bits(int(text, 2), len(text))


def test_stuffing_rule():
    assert _stuff("00000") == 1
    assert _stuff("0000000000") == 2
    assert _stuff("10" * 20) == 0
    assert _stuff("000001111") == 2  # the stuffed 1 joins the four ones that follow
    assert _stuff("00000111") == 1
    assert _stuff("1" * 17) == 3  # each stuffed 0 breaks the run of ones


def test_bad_frames_and_load_percent():
    with pytest.raises(ValueError, match="11-bit"):
        frame_bits(0x800, b"")
    with pytest.raises(ValueError, match="at most 8"):
        frame_bits(0x100, bytes(9))
    assert bus_load_pct(500_000, 1.0) == 100.0
    assert bus_load_pct(4000 * 125, 2.0) == 50.0
    assert bus_load_pct(10, 0) == 0.0
