"""E2E protection against the autosar-e2e package, and the receiver's state machine."""

import pytest
from e2e.p01 import e2e_p01_check, e2e_p01_protect
from hypothesis import given
from hypothesis import strategies as st

from protocol.codec import Codec
from protocol.e2e import COUNTER_MODULO, E2EChecker, E2EStatus, crc8, data_id_crc_start, protect

CODEC = Codec()
PROTECTED = [m for m in CODEC.messages if m.protected]


@pytest.mark.parametrize("message", PROTECTED, ids=lambda m: m.name)
def test_crc_matches_autosar_profile1_for_all_counters(message):
    """Our frames for each of the 15 counter values equal autosar-e2e's Profile 1 protect."""
    values = [s.raw_max // 3 for s in message.signals]
    if message.multiplexed:
        values = [1, 12345]
    for counter in range(COUNTER_MODULO):
        message.counter = counter
        message.pack_raw(values)
        ours = bytes(message.data)
        oracle = bytearray(ours)
        oracle[0] = 0
        e2e_p01_protect(oracle, message.data_id, increment_counter=False)
        assert ours == bytes(oracle), f"{message.name} counter {counter}"
        assert ours[1] & 0x0F == counter
        assert e2e_p01_check(bytearray(ours), message.data_id)


def test_crc8_check_value_of_the_polynomial():
    # CRC-8 poly 0x1D, init 0, no final XOR: check value of "123456789" is 0x37
    assert crc8(b"123456789", 0) == 0x37


def test_counter_wraps_after_14():
    m = CODEC["PlantSensors"]
    m.counter = 13
    seen = []
    for _ in range(4):
        m.pack_raw((0, 0, 0))
        seen.append(m.data[1] & 0x0F)
    assert seen == [13, 14, 0, 1]


@given(
    payload=st.binary(min_size=7, max_size=7), bit=st.integers(0, 63), counter=st.integers(0, 14)
)
def test_every_single_bit_flip_is_wrongcrc(payload, bit, counter):
    frame = bytearray(b"\x00" + payload)
    protect(frame, 0x1002, counter)
    checker = E2EChecker(0x1002)
    assert checker.check(frame) == E2EStatus.OK
    frame[bit // 8] ^= 1 << (bit % 8)
    assert E2EChecker(0x1002).check(frame) == E2EStatus.WRONGCRC


def test_frame_with_another_data_id_is_wrongcrc():
    frame = bytearray(8)
    protect(frame, 0x1002, 3)
    assert E2EChecker(0x1003).check(frame) == E2EStatus.WRONGCRC


def test_checker_sequence_states_and_timeout_in_ticks():
    m = CODEC["Demand"]
    m.counter = 0
    checker = m.checker(max_delta=2, timeout_ticks=3)

    def send():
        m.pack_raw((1, 0, 5000, 0, 0))
        return bytes(m.data)

    first = send()
    assert checker.check(first) == E2EStatus.OK
    assert checker.check(first) == E2EStatus.REPEATED
    send()  # one frame lost: still within max_delta=2
    assert checker.check(send()) == E2EStatus.OK
    send()
    send()  # two lost: beyond max_delta
    assert checker.check(send()) == E2EStatus.WRONGSEQUENCE
    assert checker.check(send()) == E2EStatus.OK
    assert [checker.tick() for _ in range(4)] == [E2EStatus.OK] * 3 + [E2EStatus.NONEWDATA]
    assert checker.check(send()) == E2EStatus.OK  # recovers on the next good frame
    assert checker.counts[E2EStatus.NONEWDATA] == 1
    assert checker.counts[E2EStatus.REPEATED] == 1


def test_counter_value_15_is_never_accepted():
    frame = bytearray(8)
    protect(frame, 0x1002, 0)
    frame[1] |= 0x0F
    frame[0] = crc8(memoryview(frame)[1:], data_id_crc_start(0x1002))
    assert E2EChecker(0x1002).check(frame) == E2EStatus.WRONGCRC


def test_bad_checker_parameters_are_refused():
    with pytest.raises(ValueError, match="max_delta"):
        E2EChecker(1, max_delta=0)
    with pytest.raises(ValueError, match="timeout"):
        E2EChecker(1, timeout_ticks=0)
    with pytest.raises(ValueError, match="data ID"):
        E2EChecker(70000)


def test_counter_15_with_a_valid_crc_is_wrongcrc_and_not_remembered():
    """15 is never sent: a frame carrying it is corrupt however its CRC came out, and the next
    frame is judged from the counter before it (AUTOSAR's check keeps no state of such a frame)."""
    checker = E2EChecker(0x1002)
    for counter, expected in ((4, E2EStatus.OK), (15, E2EStatus.WRONGCRC), (5, E2EStatus.OK)):
        frame = bytearray(8)
        frame[1] = counter  # protect() takes the counter modulo 15: 15 is written by hand
        frame[0] = crc8(frame[1:], data_id_crc_start(0x1002))
        assert checker.check(frame) == expected, counter
    assert checker.check(frame) == E2EStatus.REPEATED  # the 5 was remembered, the 15 was not
