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
_BLOCK_FRAMES = 4096  # frames counted at once by the table method (its arrays stay in the cache)


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


_TABLES: dict[str, np.ndarray] = {}


def _tables() -> dict[str, np.ndarray]:
    """CRC-15 per byte, and the bit-stuffing automaton per byte (and per 1..7 leading bits).

    Stuffing state: 0 before the first bit, else 1 + 4 * last bit + (run length - 1), run 1..4
    (a fifth equal bit brings a complement bit, which starts the next run).
    """
    if _TABLES:
        return _TABLES
    crc = np.zeros(256, np.int32)
    for byte in range(256):
        c = 0
        for i in range(7, -1, -1):
            feedback = ((byte >> i) & 1) ^ ((c >> 14) & 1)
            c = ((c << 1) & 0x7FFF) ^ (feedback * CRC15_POLY)
        crc[byte] = c
    # next[bits][state, value]: state after `bits` leading bits of a byte; stuffed likewise
    # (every state and byte value at once, a bit at a time)
    nxt = np.zeros((9, 9, 256), np.int64)
    stuffed = np.zeros((9, 9, 256), np.int64)
    st = np.repeat(np.arange(9), 256)
    byte = np.tile(np.arange(256), 9)
    count = np.zeros(9 * 256, np.int64)
    for bits in range(1, 9):
        b = (byte >> (8 - bits)) & 1
        last, run = (st - 1) // 4, (st - 1) % 4 + 1
        same = (st != 0) & (b == last)
        hit = same & (run == 4)
        count = count + hit
        st = np.where(same & ~hit, 1 + 4 * b + run, 1 + 4 * np.where(hit, 1 - b, b))
        nxt[bits] = st.reshape(9, 256)
        stuffed[bits] = count.reshape(9, 256)
    # one flat table per bit count: index state * 256 + byte, entry next state * 256 + stuffed
    # bits (the next state comes out ready as the next index's base)
    step = (nxt * 256 + stuffed).reshape(9, -1).astype(np.int32)
    _TABLES.update(crc=crc, step8=step[8], step2=step[2])
    return _TABLES


def frames_bits_bytewise(ids: np.ndarray, dlc: int, data: np.ndarray) -> np.ndarray:
    """As :func:`frames_bits` (same lengths), a byte at a time with tables instead of a bit at
    a time: several times faster on large batches (taken in blocks that stay in the cache)."""
    if np.any(ids >= 0x800):
        raise ValueError("an ID does not fit 11 bits")
    if not 0 <= dlc <= 8:
        raise ValueError(f"DLC {dlc}: classical CAN carries at most 8 data bytes")
    if len(ids) > _BLOCK_FRAMES:
        return np.concatenate(
            [
                _bits_bytewise(ids[i : i + _BLOCK_FRAMES], dlc, data[i : i + _BLOCK_FRAMES])
                for i in range(0, len(ids), _BLOCK_FRAMES)
            ]
        )
    return _bits_bytewise(ids, dlc, data)


def _bits_bytewise(ids: np.ndarray, dlc: int, data: np.ndarray) -> np.ndarray:
    t = _tables()
    n = len(ids)
    ids = ids.astype(np.int64)
    # the stuffed part: SOF, ID, RTR, IDE, r0, DLC (19 bits), data, CRC (15 bits); 34 + 8 dlc
    # bits in all, so 4 + dlc whole bytes and 2 bits. Header bits 0..18 as one integer.
    header = (ids << 7) | dlc  # SOF 0 | ID (11) | RTR, IDE, r0 = 0 | DLC (4)
    # CRC-15 over the body: 3 header bits one at a time, then whole bytes
    crc = np.zeros(n, np.int64)
    for i in range(18, 15, -1):
        feedback = ((header >> i) & 1) ^ ((crc >> 14) & 1)
        crc = ((crc << 1) & 0x7FFF) ^ (feedback * CRC15_POLY)
    body = np.empty((n, 2 + dlc), np.int64)
    body[:, 0] = (header >> 8) & 0xFF
    body[:, 1] = header & 0xFF
    body[:, 2:] = data[:, :dlc]
    for j in range(2 + dlc):
        crc = ((crc << 8) & 0x7FFF) ^ t["crc"][((crc >> 7) ^ body[:, j]) & 0xFF]
    # the whole stream as bytes: 3 header bits, the body bytes, the CRC; shifted to start at
    # a byte boundary: stream = header bits 18..16, body (16 + 8 dlc bits), crc (15 bits)
    stream = np.empty((n, 5 + dlc), np.int64)
    top = (header >> 16) & 0b111  # the 3 leading bits
    carry = top
    for j in range(2 + dlc):  # each byte: 3 bits carried in, 5 bits of the body byte
        stream[:, j] = (carry << 5) | (body[:, j] >> 3)
        carry = body[:, j] & 0b111
    # then 3 carried bits + 15 CRC bits = 18 bits: two whole bytes and 2 bits
    tail = (carry << 15) | crc
    stream[:, 2 + dlc] = (tail >> 10) & 0xFF
    stream[:, 3 + dlc] = (tail >> 2) & 0xFF
    stream[:, 4 + dlc] = (tail & 0b11) << 6
    stream = stream.astype(np.int32)
    step8 = t["step8"]
    base = np.zeros(n, np.int32)  # state * 256
    stuffed = np.zeros(n, np.int32)
    for j in range(4 + dlc):
        entry = step8.take(base | stream[:, j])
        stuffed += entry & 0xFF
        base = entry & ~0xFF
    stuffed += t["step2"].take(base | stream[:, 4 + dlc]) & 0xFF
    return 34 + 8 * dlc + stuffed + _UNSTUFFED_TAIL_BITS


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
                self.bits += int(frames_bits_bytewise(ids[rows], int(dlc), records[rows, 3:]).sum())
            self.frames += self._pending
            self._buffer.clear()
            self._pending = 0
        return self.bits


def bus_load_pct(total_bits: int, seconds: float, bitrate: int = DEFAULT_BITRATE) -> float:
    """Percent of the bus's capacity used by ``total_bits`` over ``seconds``."""
    if seconds <= 0:
        return 0.0
    return 100.0 * total_bits / (bitrate * seconds)
