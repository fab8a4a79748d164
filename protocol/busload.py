"""Bus load of classical CAN: exact frame lengths in bits, stuff bits included.

A base-format data frame is SOF, 11-bit ID, RTR, IDE, r0, 4-bit DLC, the data and a 15-bit CRC,
all subject to bit stuffing (a complement bit after five equal bits; the stuff bit counts towards
the next run), followed by 13 unstuffed bits: CRC delimiter, ACK slot, ACK delimiter, 7-bit end of
frame and 3-bit intermission. :class:`BitCounter` takes frames one by one at the cost of an append
and works out their lengths in batches, vectorised over frames.
"""

from __future__ import annotations

import numpy as np

DEFAULT_BITRATE = 500_000
CRC15_POLY = 0x4599  # ISO 11898-1: x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1
_UNSTUFFED_TAIL_BITS = 13
_RECORD = 11  # bytes per frame in the batch buffer: ID (2), DLC (1), data (8)


def frames_bits(ids: np.ndarray, dlc: int, data: np.ndarray) -> np.ndarray:
    """Lengths on the wire of base-format frames with one DLC: ``data`` is (frames, dlc) uint8."""
    if np.any(ids >= 0x800):
        raise ValueError("an ID does not fit 11 bits")
    if not 0 <= dlc <= 8:
        raise ValueError(f"DLC {dlc}: classical CAN carries at most 8 data bytes")
    n = len(ids)
    id_bits = ((ids[:, None].astype(np.uint16) >> np.arange(10, -1, -1)) & 1).astype(np.uint8)
    dlc_bits = np.broadcast_to(np.array([(dlc >> i) & 1 for i in (3, 2, 1, 0)], np.uint8), (n, 4))
    body = np.concatenate(
        [
            np.zeros((n, 1), np.uint8),
            id_bits,
            np.zeros((n, 3), np.uint8),
            dlc_bits,
            np.unpackbits(data[:, :dlc], axis=1),
        ],
        axis=1,
    )
    crc = np.zeros(n, np.int32)
    for column in body.T:  # CRC-15, one bit position at a time for every frame
        feedback = column ^ ((crc >> 14) & 1)
        crc = ((crc << 1) & 0x7FFF) ^ (feedback * CRC15_POLY)
    crc_bits = ((crc[:, None] >> np.arange(14, -1, -1)) & 1).astype(np.uint8)
    bits = np.concatenate([body, crc_bits], axis=1)
    last = np.full(n, 2, np.int8)  # 2: no bit yet
    run = np.zeros(n, np.int8)
    stuffed = np.zeros(n, np.int32)
    for column in bits.T:
        run = np.where(column == last, run + 1, 1).astype(np.int8)
        last = column.astype(np.int8)
        hit = run == 5  # a complement bit goes in and starts the next run
        stuffed += hit
        last = np.where(hit, 1 - column, last).astype(np.int8)
        run = np.where(hit, 1, run).astype(np.int8)
    return bits.shape[1] + stuffed + _UNSTUFFED_TAIL_BITS


class BitCounter:
    """Adds up the exact length of every frame it is given (batches of ``batch`` frames)."""

    def __init__(self, batch: int = 65_536) -> None:
        self.batch = batch
        self._buffer = bytearray()
        self._pending = 0
        self.bits = 0
        self.frames = 0

    def add(self, frame_id: int, data: bytes | bytearray) -> None:
        n = len(data)
        self._buffer += frame_id.to_bytes(2, "little")
        self._buffer.append(n)
        self._buffer += data
        if n < 8:
            self._buffer += bytes(8 - n)
        self._pending += 1
        if self._pending >= self.batch:
            self.flush()

    def add_many(self, frame_ids: np.ndarray, payload: np.ndarray, lengths: np.ndarray) -> None:
        """Many frames at once, as :meth:`add` one by one: ``payload`` is (frames, 8) uint8,
        zero beyond each frame's ``lengths`` (0..8)."""
        n = len(frame_ids)
        if n == 0:
            return
        records = np.empty((n, _RECORD), np.uint8)
        ids = np.asarray(frame_ids, np.int64)
        records[:, 0] = ids & 0xFF
        records[:, 1] = (ids >> 8) & 0xFF
        records[:, 2] = lengths
        records[:, 3:] = payload
        start = 0
        while start < n:  # batches of ``batch`` frames, as add() counts them
            take = min(n - start, self.batch - self._pending)
            self._buffer += records[start : start + take].tobytes()
            self._pending += take
            start += take
            if self._pending >= self.batch:
                self.flush()

    def flush(self) -> int:
        """Count the buffered frames; returns the total bits so far."""
        if self._pending:
            records = np.frombuffer(bytes(self._buffer), np.uint8).reshape(-1, _RECORD)
            ids = records[:, 0].astype(np.uint16) | (records[:, 1].astype(np.uint16) << 8)
            for dlc in np.unique(records[:, 2]):
                rows = records[:, 2] == dlc
                self.bits += int(frames_bits(ids[rows], int(dlc), records[rows, 3:]).sum())
            self.frames += self._pending
            self._buffer.clear()
            self._pending = 0
        return self.bits


def bus_load_pct(total_bits: int, seconds: float, bitrate: int = DEFAULT_BITRATE) -> float:
    """Percent of the bus's capacity used by ``total_bits`` over ``seconds``."""
    if seconds <= 0:
        return 0.0
    return 100.0 * total_bits / (bitrate * seconds)
