"""Parameter storage as on a microcontroller: an emulated flash image with two slots.

The image file holds two slots of ``SLOT_SIZE`` bytes. A slot is a 16-byte header and the stored
set:

    magic "TJP1" | sequence u32 | length u16 | CRC-16/CCITT-FALSE u16 | 4 bytes 0xFF | payload

(big-endian); the CRC covers the sequence, the length and the payload. A save goes to the slot
that does not hold the newest valid set, as flash would be written: erase the slot (0xFF), program
the payload page by page, program the header last. The other slot is never touched, so a power
cut (the process killed) at any point of a save leaves the last good set readable: at start-up
:func:`load` takes the valid slot with the highest sequence number, or reports that neither is
valid (the ECU then runs on its defaults and flags it).

:class:`SlotWriter` performs a save one flash operation per :meth:`SlotWriter.step`, so that the
ECU can spread it over ticks (one operation per tick) and never stall its control loop. The
emulation does not fsync: a killed process loses nothing the kernel has, which is the power cut
it models. Sequence numbers are 32-bit and not expected to wrap (flash endures about 10^5 erase
cycles).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

from ecu.service.crc import crc16

MAGIC = b"TJP1"
HEADER = struct.Struct(">4sIHH4x")
SLOT_SIZE = 4096  # a 4 KiB erase sector; the whole table packs to about 2.2 KiB
SLOTS = 2
IMAGE_SIZE = SLOT_SIZE * SLOTS
PAGE_SIZE = 256  # bytes programmed per operation
ERASED = 0xFF
MAX_STORED = SLOT_SIZE - HEADER.size


class StorageError(OSError):
    """The flash image file cannot be used; the message names the file."""


@dataclass(frozen=True)
class Slot:
    index: int
    sequence: int
    payload: bytes


def _slot_crc(sequence: int, payload: bytes) -> int:
    return crc16(struct.pack(">IH", sequence, len(payload)) + payload)


def parse_slot(index: int, raw: bytes) -> Slot | None:
    """The slot's stored set if its header and CRC are valid, else None."""
    if len(raw) < HEADER.size:
        return None
    magic, sequence, length, crc = HEADER.unpack_from(raw)
    if magic != MAGIC or length > MAX_STORED:
        return None
    payload = raw[HEADER.size : HEADER.size + length]
    if len(payload) != length or _slot_crc(sequence, payload) != crc:
        return None
    return Slot(index, sequence, payload)


def read_slots(path: Path) -> list[Slot]:
    """The valid slots of an image (a missing file has none)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise StorageError(f"{path}: cannot read the flash image: {exc}") from None
    slots = (parse_slot(i, data[i * SLOT_SIZE : (i + 1) * SLOT_SIZE]) for i in range(SLOTS))
    return [s for s in slots if s is not None]


def load(path: Path) -> Slot | None:
    """The newest valid slot, or None when neither is valid."""
    slots = read_slots(path)
    return max(slots, key=lambda s: s.sequence) if slots else None


class FlashImage:
    """An open image file, created erased (0xFF) at its full size when missing or short."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            size = os.fstat(self.fd).st_size
            if size < IMAGE_SIZE:
                os.pwrite(self.fd, bytes([ERASED]) * (IMAGE_SIZE - size), size)
        except OSError as exc:
            raise StorageError(f"{path}: cannot open the flash image: {exc}") from None

    def close(self) -> None:
        os.close(self.fd)

    def newest(self) -> Slot | None:
        return load(self.path)

    def writer(self, payload: bytes, page_size: int = PAGE_SIZE) -> SlotWriter:
        """A save of ``payload`` into the slot after the newest valid one."""
        if len(payload) > MAX_STORED:
            raise ValueError(f"stored set of {len(payload)} bytes exceeds {MAX_STORED}")
        newest = self.newest()
        index = 0 if newest is None else 1 - newest.index
        sequence = 1 if newest is None else (newest.sequence + 1) & 0xFFFFFFFF
        return SlotWriter(self.fd, index, sequence, payload, page_size)

    def save(self, payload: bytes) -> Slot:
        """A whole save at once (tools and tests; the ECU steps a :class:`SlotWriter`)."""
        writer = self.writer(payload)
        while not writer.step():
            pass
        return writer.slot


class SlotWriter:
    """One save as a list of flash operations (erase, pages, header), one per :meth:`step`."""

    def __init__(self, fd: int, index: int, sequence: int, payload: bytes, page_size: int) -> None:
        base = index * SLOT_SIZE
        header = HEADER.pack(MAGIC, sequence, len(payload), _slot_crc(sequence, payload))
        self._ops: list[tuple[int, bytes]] = [(base, bytes([ERASED]) * SLOT_SIZE)]
        for off in range(0, len(payload), page_size):
            self._ops.append((base + HEADER.size + off, payload[off : off + page_size]))
        self._ops.append((base, header))
        self._fd = fd
        self._next = 0
        self.slot = Slot(index, sequence, payload)

    @property
    def operations(self) -> int:
        return len(self._ops)

    def step(self) -> bool:
        """Perform the next operation; True once the save is complete."""
        if self._next < len(self._ops):
            offset, data = self._ops[self._next]
            os.pwrite(self._fd, data, offset)
            self._next += 1
        return self._next >= len(self._ops)
