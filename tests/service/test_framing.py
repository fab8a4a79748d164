"""Frames: CRC and COBS against independent references; the decoder under fuzzing."""

import crcmod.predefined
import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from ecu.service.crc import crc16
from ecu.service.framing import MAX_ENCODED, MAX_PAYLOAD, FrameDecoder, FrameStats, encode_frame
from ecu.service.message import Kind, Message, MessageError, Service, Status, pack, unpack

payloads = st.binary(min_size=1, max_size=MAX_PAYLOAD)
SETTINGS = settings(max_examples=300, deadline=None, derandomize=True)


def test_crc_check_value_and_crcmod_catalogue():
    assert crc16(b"123456789") == 0x29B1  # the catalogue's check value for CRC-16/CCITT-FALSE
    reference = crcmod.predefined.Crc("crc-ccitt-false")
    assert (reference.poly, reference.initCrc, reference.reverse, reference.xorOut) == (
        0x11021,
        0xFFFF,
        False,
        0x0000,
    )
    for data in (b"", b"\x00", b"\xff" * 300, bytes(range(256))):
        assert crc16(data) == crcmod.mkCrcFun(0x11021, 0xFFFF, False, 0)(data)


def test_frame_layout():
    payload = b"\x01\x00\x02"
    frame = encode_frame(payload)
    assert frame[0] == 0 and frame[-1] == 0 and 0 not in frame[1:-1]
    body = cobs.decode(frame[1:-1])
    assert body == payload + crc16(payload).to_bytes(2, "big")


def test_payload_over_the_limit_is_refused():
    encode_frame(b"x" * MAX_PAYLOAD)
    with pytest.raises(ValueError, match="exceeds the 256-byte limit"):
        encode_frame(b"x" * (MAX_PAYLOAD + 1))


def test_bad_frames_are_dropped_and_counted():
    d = FrameDecoder()
    good = encode_frame(b"hello")
    bad_crc = bytearray(good)
    bad_crc[3] ^= 0x01  # a data byte: COBS still decodes, the CRC does not match
    assert d.feed(bytes(bad_crc) + b"\x00\x05\x00" + b"\x00\x02\x01\x00") == []
    assert (d.stats.crc_errors, d.stats.malformed) == (1, 2)  # \x05 lies; one byte is no CRC
    assert d.feed(b"\x07" * (MAX_ENCODED + 1)) == []  # no delimiter: skipped, memory bounded
    assert d.stats.oversized == 1
    assert d.feed(b"\x07" * 10_000 + good) == [b"hello"]
    assert d.stats == FrameStats(frames=1, malformed=2, crc_errors=1, oversized=1)


@SETTINGS
@given(st.lists(payloads, min_size=1, max_size=8), st.data())
def test_frames_decode_across_any_split(frames, data):
    wire = b"".join(encode_frame(p) for p in frames)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(wire)), max_size=6)))
    d = FrameDecoder()
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(wire)], strict=True):
        got += d.feed(wire[a:b])
    assert got == frames
    assert d.stats == FrameStats(frames=len(frames))


def _is_subsequence(wanted: list[bytes], got: list[bytes]) -> bool:
    it = iter(got)
    return all(any(w == g for g in it) for w in wanted)


@SETTINGS
@given(st.lists(st.tuples(st.binary(max_size=600), payloads), max_size=8), st.binary())
def test_valid_frames_survive_noise_between_them(items, tail):
    """Random bytes between frames never raise, and every valid frame is still decoded."""
    wire = b"".join(noise + encode_frame(p) for noise, p in items) + tail
    d = FrameDecoder()
    assert _is_subsequence([p for _, p in items], d.feed(wire))


@SETTINGS
@given(st.lists(payloads, min_size=1, max_size=6), st.data())
def test_bit_flips_lose_only_the_frames_they_touch(frames, data):
    encoded = [encode_frame(p) for p in frames]
    wire = bytearray(b"".join(encoded))
    flips = data.draw(st.lists(st.integers(0, 8 * len(wire) - 1), max_size=6))
    touched = {bit // 8 for bit in flips}
    for bit in flips:
        wire[bit // 8] ^= 1 << (bit % 8)
    intact = []
    pos = 0
    for payload, frame in zip(frames, encoded, strict=True):
        if not touched & set(range(pos, pos + len(frame))):
            intact.append(payload)
        pos += len(frame)
    d = FrameDecoder()
    got = d.feed(bytes(wire))
    assert _is_subsequence(intact, got)
    assert d.stats.frames == len(got)


@SETTINGS
@given(st.lists(payloads, min_size=1, max_size=6), st.data(), payloads)
def test_truncated_stream_then_resync(frames, data, after):
    wire = b"".join(encode_frame(p) for p in frames)
    cut = data.draw(st.integers(0, len(wire)))
    complete = []
    pos = 0
    for p in frames:
        pos += len(encode_frame(p))
        if pos <= cut:
            complete.append(p)
    d = FrameDecoder()
    got = d.feed(wire[:cut])
    assert got == complete
    # the next frame decodes; its leading delimiter also ends a frame cut just before its own
    more = d.feed(encode_frame(after))
    assert more[-1] == after and len(more) <= 2


@SETTINGS
@given(st.binary(max_size=2 * MAX_ENCODED))
def test_random_bytes_never_raise(noise):
    d = FrameDecoder()
    for payload in d.feed(noise):
        try:
            unpack(payload)
        except MessageError:
            pass


def test_message_round_trip_and_errors():
    msg = Message(Kind.RESPONSE, 65535, Service.PARAM_READ, Status.OK, {"name": "pid_kp", "raw": 7})
    assert unpack(pack(msg)) == msg
    with pytest.raises(MessageError, match="shorter than its header"):
        unpack(b"\x01\x01")
    with pytest.raises(MessageError, match="unknown message kind 9"):
        unpack(b"\x01\x09\x00\x01\x01\x00\xc0")
    with pytest.raises(MessageError, match="not msgpack"):
        unpack(b"\x01\x01\x00\x01\x01\x00\xc1")  # 0xC1 is never used in msgpack
    other = unpack(b"\x02\x01\x00\x01\x01\x00\xc1")  # another version: header only
    assert (other.version, other.body) == (2, None)
    with pytest.raises(ValueError, match="exceeds 256"):
        pack(Message(Kind.REQUEST, 1, Service.IDENTIFY, body="x" * 300))
