from hypothesis import given
from hypothesis import strategies as st

from protocol.busload import _crc15, _stuff_bits, bus_load_pct, frame_bits


def test_crc15_leaves_zero_remainder():
    # ISO 11898-1 polynomial x^15+x^14+x^10+x^8+x^7+x^4+x^3+1 over the frame's bits
    bits = (
        [0]
        + [int(b) for b in f"{0x123:011b}"]
        + [0, 0, 0]
        + [0, 0, 0, 1]
        + [int(b) for b in f"{0x11:08b}"]
    )
    crc = _crc15(bits)
    # appending the CRC makes the remainder zero: the defining property of a CRC
    assert _crc15(bits + [int(b) for b in f"{crc:015b}"]) == 0


def test_stuffing_rule():
    assert _stuff_bits([0] * 5) == 1
    assert _stuff_bits([0] * 10) == 2  # 00000s0000 0s: the stuff bit starts a new run
    assert _stuff_bits([1, 0] * 20) == 0
    # the stuffed 1 joins the four ones that follow: five ones, stuffed again
    assert _stuff_bits([0, 0, 0, 0, 0, 1, 1, 1, 1]) == 2
    assert _stuff_bits([0, 0, 0, 0, 0, 1, 1, 1]) == 1


@given(st.integers(0, 0x7FF), st.binary(min_size=8, max_size=8))
def test_eight_byte_frames_are_between_111_and_135_bits(frame_id, data):
    bits = frame_bits(frame_id, data)
    # 111 unstuffed bits; worst-case stuffing of the 98 stuffable bits adds 24 at most
    assert 111 <= bits <= 135


def test_all_zero_frame_length():
    # SOF..CRC = 1+11+3+4+64+15 = 98 bits; zeros everywhere stuff heavily
    assert frame_bits(0, bytes(8)) > 111


def test_load_percent():
    assert bus_load_pct(500_000, 1.0) == 100.0
    assert bus_load_pct(4000 * 125, 2.0) == 50.0
    assert bus_load_pct(10, 0) == 0.0
