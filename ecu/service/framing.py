"""COBS frames with a CRC-16/CCITT-FALSE, delimited by zero bytes.

On the wire a frame is ``00 COBS(payload || CRC16(payload), big-endian) 00``: the leading
delimiter ends whatever noise came before, so a receiver joining mid-stream or after line noise
resynchronises on the next frame. COBS is the ``cobs`` package's (C implementation).

:class:`FrameDecoder` is fed bytes as they arrive and returns the good payloads; it never raises
on input. Frames that do not COBS-decode or are too short are counted as ``malformed``, those
whose CRC fails as ``crc_errors``, and those longer than the limit as ``oversized`` (their bytes
are skipped up to the next delimiter, so the decoder's memory stays bounded).
"""

from __future__ import annotations

from dataclasses import dataclass

from cobs import cobs

from ecu.service.crc import crc16

DELIMITER = 0
MAX_PAYLOAD = 256  # bytes of message (header and body) in one frame
CRC_BYTES = 2
# COBS adds one code byte per 254 bytes (and one at the start)
MAX_ENCODED = MAX_PAYLOAD + CRC_BYTES + (MAX_PAYLOAD + CRC_BYTES) // 254 + 1


def encode_frame(payload: bytes) -> bytes:
    """The wire bytes of one frame (delimiters included)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    body = payload + crc16(payload).to_bytes(CRC_BYTES, "big")
    return b"\x00" + cobs.encode(body) + b"\x00"


@dataclass
class FrameStats:
    frames: int = 0  # good frames decoded
    malformed: int = 0  # not valid COBS, or shorter than a CRC
    crc_errors: int = 0
    oversized: int = 0  # longer than MAX_ENCODED before their delimiter


class FrameDecoder:
    """Incremental frame decoder with bounded memory (see the module docstring)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._skipping = False  # inside an oversized frame: drop bytes up to the delimiter
        self.stats = FrameStats()

    def feed(self, data: bytes | bytearray) -> list[bytes]:
        """Take received bytes; return the payloads of the frames they complete, in order."""
        payloads: list[bytes] = []
        start = 0
        while True:
            end = data.find(DELIMITER, start)
            if end < 0:
                self._take(data[start:])
                return payloads
            self._take(data[start:end])
            payload = self._end_of_frame()
            if payload is not None:
                payloads.append(payload)
            start = end + 1

    def _take(self, chunk: bytes | bytearray) -> None:
        if self._skipping or not chunk:
            return
        if len(self._buf) + len(chunk) > MAX_ENCODED:
            self.stats.oversized += 1
            self._skipping = True
            self._buf.clear()
            return
        self._buf += chunk

    def _end_of_frame(self) -> bytes | None:
        if self._skipping:
            self._skipping = False
            return None
        if not self._buf:
            return None  # back-to-back delimiters
        encoded = bytes(self._buf)
        self._buf.clear()
        try:
            body = cobs.decode(encoded)
        except cobs.DecodeError:
            self.stats.malformed += 1
            return None
        if len(body) < CRC_BYTES:
            self.stats.malformed += 1
            return None
        payload = body[:-CRC_BYTES]
        if crc16(payload) != int.from_bytes(body[-CRC_BYTES:], "big"):
            self.stats.crc_errors += 1
            return None
        self.stats.frames += 1
        return payload
