"""End-to-end protection of safety frames, AUTOSAR Profile 1 layout (data ID mode "both").

Byte 0 holds a CRC-8 (polynomial 0x1D, initial value 0x00, no final XOR) computed over the data ID
low byte, the data ID high byte and bytes 1..7 of the frame; the low nibble of byte 1 holds an alive
counter 0..14 that the sender increments per frame (15 is never sent, as in Profile 1).

The receiver side (:class:`E2EChecker`) classifies each frame as OK, REPEATED, WRONGSEQUENCE or
WRONGCRC and, when no frame has arrived for more than ``timeout_ticks`` calls of :meth:`tick`,
reports NONEWDATA. Time is counted in ticks of the caller, never in wall time, so a lockstep run
behaves the same at any speed.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import IntEnum

import crcmod

COUNTER_MODULO = 15  # alive counter runs 0..14
_crc8 = crcmod.mkCrcFun(0x11D, initCrc=0x00, rev=False, xorOut=0x00)


class E2EStatus(IntEnum):
    OK = 0
    REPEATED = 1
    WRONGSEQUENCE = 2
    WRONGCRC = 3
    NONEWDATA = 4


# the statuses the checker gives, bound once (cheaper than the enum's attributes per frame)
_OK, _REPEATED, _WRONGSEQUENCE, _WRONGCRC = (
    E2EStatus.OK,
    E2EStatus.REPEATED,
    E2EStatus.WRONGSEQUENCE,
    E2EStatus.WRONGCRC,
)


def data_id_crc_start(data_id: int) -> int:
    """CRC register after the two data ID bytes (low byte first): the start for the payload."""
    if not 0 <= data_id <= 0xFFFF:
        raise ValueError(f"E2E data ID {data_id} is outside 0..65535")
    return _crc8(bytes((data_id & 0xFF, data_id >> 8)))


# crc8(payload_after_crc, crc_start) -> int: CRC-8 of bytes 1..n of a frame, continuing from
# data_id_crc_start (crcmod's function itself, with no wrapper of ours on the hot path)
crc8: Callable[[bytes | bytearray | memoryview, int], int] = _crc8


_TABLE = None  # CRC-8 table for crc8_rows, as a numpy array (numpy imported on first use)


def crc8_rows(data, crc_start: int):
    """Vectorised :func:`crc8`: the CRC-8 of every row of ``data`` ((frames, bytes) uint8 numpy
    array, bytes 1..n of each frame), continuing from ``crc_start``; a uint8 array."""
    global _TABLE
    import numpy as np

    if _TABLE is None:
        _TABLE = np.array([_crc8(bytes((b,)), 0) for b in range(256)], np.uint8)
    crc = np.full(len(data), crc_start, np.uint8)
    for j in range(data.shape[1]):
        crc = _TABLE[crc ^ data[:, j]]
    return crc


def protect(frame: bytearray, data_id: int, counter: int) -> None:
    """Write ``counter`` into the low nibble of byte 1 and the CRC into byte 0 (in place)."""
    frame[1] = (frame[1] & 0xF0) | (counter % COUNTER_MODULO)
    frame[0] = _crc8(memoryview(frame)[1:], data_id_crc_start(data_id))


class E2EChecker:
    """Receiver-side state machine for one protected message.

    ``max_delta`` is how many frames may be lost between two received ones and still count as OK
    (1 means every frame must arrive); ``timeout_ticks`` is how many :meth:`tick` calls without a
    frame are tolerated before the status becomes NONEWDATA.
    """

    __slots__ = (
        "_crc_start",
        "max_delta",
        "timeout_ticks",
        "_last_counter",
        "_ticks_since",
        "status",
        "counts",
    )

    def __init__(self, data_id: int, *, max_delta: int = 1, timeout_ticks: int = 10) -> None:
        if not 1 <= max_delta <= COUNTER_MODULO - 1:
            raise ValueError(f"max_delta {max_delta} is outside 1..14")
        if timeout_ticks < 1:
            raise ValueError(f"timeout_ticks {timeout_ticks} must be at least 1")
        self._crc_start = data_id_crc_start(data_id)
        self.max_delta = max_delta
        self.timeout_ticks = timeout_ticks
        self._last_counter = -1
        self._ticks_since = 0
        self.status = E2EStatus.NONEWDATA
        self.counts = [0] * len(E2EStatus)

    def check(self, frame: bytes | bytearray | memoryview) -> E2EStatus:
        """Classify one received frame and remember its counter when it is accepted."""
        counter = frame[1] & 0x0F if len(frame) >= 2 else COUNTER_MODULO
        if counter >= COUNTER_MODULO or _crc8(frame[1:], self._crc_start) != frame[0]:
            status = _WRONGCRC  # (15 is never sent: a corrupted frame) nothing is remembered
        else:
            last = self._last_counter
            if last < 0:
                status = _OK
            else:
                delta = (counter - last) % COUNTER_MODULO
                if delta == 0:
                    status = _REPEATED
                elif delta <= self.max_delta:
                    status = _OK
                else:
                    status = _WRONGSEQUENCE
            if status is not _REPEATED:
                self._last_counter = counter
                self._ticks_since = 0
        self.status = status
        self.counts[status] += 1
        return status

    def tick(self) -> E2EStatus:
        """Advance one tick of the receiver's clock; report NONEWDATA once the timeout elapses."""
        self._ticks_since += 1
        if self._ticks_since > self.timeout_ticks and self.status != E2EStatus.NONEWDATA:
            self.status = E2EStatus.NONEWDATA
            self.counts[E2EStatus.NONEWDATA] += 1
        return self.status
