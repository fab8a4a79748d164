"""The Ethernet CAN link's frames (ecu/port/eth_can.py): the payload is SocketCAN's struct
can_frame, checked against python-can's own SocketCAN packing; the bus on its UDP socket hears
only its peer."""

from __future__ import annotations

import socket

import can
from can.interfaces.socketcan.socketcan import build_can_frame, dissect_can_frame
from hypothesis import given
from hypothesis import strategies as st

from ecu.port import eth_can

messages = st.builds(
    lambda ext, ident, data: can.Message(
        arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF), is_extended_id=ext, data=data
    ),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=8),
)


def _composed_id(msg: can.Message) -> int:
    return msg.arbitration_id | (0x80000000 if msg.is_extended_id else 0)


@given(messages)
def test_payload_is_socketcans_can_frame_both_ways(msg):
    frame = eth_can.encode(msg)
    assert len(frame) == eth_can.FRAME_BYTES
    assert frame[:6] == b"\xff" * 6 and frame[12:14] == b"\x88\xb5"
    # python-can's SocketCAN reads our payload ...
    can_id, length, _flags, data = dissect_can_frame(frame[14:30])
    assert (can_id, length, data) == (_composed_id(msg), len(msg.data), bytes(msg.data))
    # ... and we read python-can's (its len8_dlc byte set or not)
    header = frame[:14]
    back = eth_can.decode(header + build_can_frame(msg))
    assert back is not None and back.equals(msg, timestamp_delta=None)
    assert eth_can.decode(frame).equals(msg, timestamp_delta=None)


def test_remote_frames_keep_their_length():
    msg = can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=3)
    back = eth_can.decode(eth_can.encode(msg))
    assert back is not None and back.is_remote_frame and back.dlc == 3 and not back.data


def test_frames_without_a_can_frame_are_not_decoded():
    good = eth_can.encode(can.Message(arbitration_id=1, is_extended_id=False, data=b"x"))
    assert eth_can.decode(good[:29]) is None  # cut short
    assert eth_can.decode(good[:12] + b"\x08\x00" + good[14:]) is None  # IPv4
    assert eth_can.decode(good[:18] + b"\x09" + good[19:]) is None  # length 9


def test_bus_hears_only_its_peer():
    mine = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mine.bind(("127.0.0.1", 0))
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    bus = eth_can.EthCanBus(mine, peer.getsockname())
    try:
        msg = can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"\x01\x02")
        stranger.sendto(eth_can.encode(msg), mine.getsockname())
        peer.sendto(eth_can.encode(msg), mine.getsockname())
        got = bus.recv(2.0)  # the stranger's came first and was dropped
        assert got is not None and got.equals(msg, timestamp_delta=None)
        assert bus.dropped == 1
        bus.send(msg)
        frame, sender = peer.recvfrom(2048)
        assert sender == mine.getsockname() and eth_can.decode(frame).equals(
            msg, timestamp_delta=None
        )
    finally:
        bus.shutdown()
        peer.close()
        stranger.close()
