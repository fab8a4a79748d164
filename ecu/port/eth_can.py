"""CAN frames in Ethernet frames, as the firmware image's Ethernet link (board_mps2_eth.c) sends
and takes them, carried by QEMU's UDP socket network backend (one Ethernet frame per datagram).

The Ethernet frame: destination (broadcast), source, EtherType 0x88B5 (IEEE 802's local
experimental type), then the 16 bytes of Linux SocketCAN's ``struct can_frame`` (``can_id``
little-endian with the 29-bit flag in bit 31 and the remote flag in bit 30, the length, three
reserved bytes, eight data bytes), padded to Ethernet's 60-byte minimum.

:class:`EthCanBus` is a python-can bus on one loopback UDP socket, exchanging datagrams with one
peer (QEMU's end); datagrams from anyone else, and Ethernet frames of any other type, are
dropped and counted.
"""

from __future__ import annotations

import select
import socket
import struct
import time

import can

ETHERTYPE_CAN = 0x88B5
BROADCAST = b"\xff" * 6
HOST_MAC = bytes.fromhex("020000000001")  # locally administered
HEADER = struct.Struct("!6s6sH")
CAN_FRAME = struct.Struct("<IB3x8s")  # struct can_frame
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_EFF_MASK = 0x1FFFFFFF
FRAME_BYTES = 60  # the Ethernet minimum without its FCS


def encode(msg: can.Message, source: bytes = HOST_MAC) -> bytes:
    """``msg`` as the Ethernet frame the image takes."""
    can_id = msg.arbitration_id & (CAN_EFF_MASK if msg.is_extended_id else 0x7FF)
    can_id |= (CAN_EFF_FLAG if msg.is_extended_id else 0) | (
        CAN_RTR_FLAG if msg.is_remote_frame else 0
    )
    data = bytes(msg.data)[:8]
    frame = HEADER.pack(BROADCAST, source, ETHERTYPE_CAN) + CAN_FRAME.pack(
        can_id, msg.dlc if msg.is_remote_frame else len(data), data.ljust(8, b"\0")
    )
    return frame.ljust(FRAME_BYTES, b"\0")


def decode(frame: bytes, timestamp: float = 0.0) -> can.Message | None:
    """The CAN frame in an Ethernet frame from the image, or None when it carries none."""
    if len(frame) < HEADER.size + CAN_FRAME.size:
        return None
    _, _, ethertype = HEADER.unpack_from(frame)
    if ethertype != ETHERTYPE_CAN:
        return None
    can_id, length, data = CAN_FRAME.unpack_from(frame, HEADER.size)
    if length > 8:
        return None
    extended = bool(can_id & CAN_EFF_FLAG)
    remote = bool(can_id & CAN_RTR_FLAG)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=can_id & (CAN_EFF_MASK if extended else 0x7FF),
        is_extended_id=extended,
        is_remote_frame=remote,
        dlc=length,
        data=None if remote else data[:length],
    )


class EthCanBus(can.BusABC):
    """A python-can bus whose frames travel as Ethernet frames in UDP datagrams to and from
    ``peer`` (host, port), on ``sock`` (a bound UDP socket; closed on shutdown)."""

    def __init__(self, sock: socket.socket, peer: tuple[str, int], **kwargs: object) -> None:
        host, port = sock.getsockname()[:2]
        super().__init__(channel=f"udp://{host}:{port}", **kwargs)
        self.channel_info = f"Ethernet CAN link, UDP {host}:{port} <-> {peer[0]}:{peer[1]}"
        self._sock = sock
        self._peer = peer
        self.dropped = 0  # datagrams from others, or not carrying a CAN frame

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            self._sock.sendto(encode(msg), self._peer)
        except OSError as exc:
            raise can.CanOperationError(f"Ethernet CAN link: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            ready, _, _ = select.select([self._sock], [], [], timeout)
            if not ready:
                return None, False
            frame, sender = self._sock.recvfrom(2048)
        except OSError as exc:
            raise can.CanOperationError(f"Ethernet CAN link: {exc}") from exc
        msg = decode(frame, time.time()) if sender[:2] == self._peer else None
        if msg is None:
            self.dropped += 1
        return msg, False

    def fileno(self) -> int:
        return self._sock.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._sock.close()
