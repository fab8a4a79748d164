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

An ECU opens its image as a :class:`FlashImage`, which holds it locked (``flock``) while open:
a second ECU on the same file is refused. A missing or empty file becomes an erased image; any
other file must be an image already (:func:`not_an_image`: its size, and each slot a stored set,
erased, or a save cut short), else it is refused and left as it is, as is anything that is not a
regular file (``/dev/null``, a folder, a pipe).

:class:`SlotWriter` performs a save one flash operation per :meth:`SlotWriter.step`, so that the
ECU can spread it over ticks (one operation per tick) and never stall its control loop. The
emulation does not fsync: a killed process loses nothing the kernel has, which is the power cut
it models. Sequence numbers are 32-bit and not expected to wrap (flash endures about 10^5 erase
cycles).
"""

from __future__ import annotations

import codecs
import fcntl
import os
import stat
import struct
import weakref
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
_ERASED_HEADER = bytes([ERASED]) * HEADER.size
_NOT_FILES = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a named pipe"),
    (stat.S_ISSOCK, "a socket"),
)


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


def _slots(data: bytes) -> list[Slot]:
    slots = (parse_slot(i, data[i * SLOT_SIZE : (i + 1) * SLOT_SIZE]) for i in range(SLOTS))
    return [s for s in slots if s is not None]


def read_slots(path: Path) -> list[Slot]:
    """The valid slots of an image (a missing file has none)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise StorageError(f"{path}: cannot read the flash image: {exc}") from None
    return _slots(data)


def load(path: Path) -> Slot | None:
    """The newest valid slot, or None when neither is valid."""
    slots = read_slots(path)
    return max(slots, key=lambda s: s.sequence) if slots else None


def not_an_image(data: bytes) -> str | None:
    """Why a file's content is not a flash image, or None when it is one: the image's size, and
    each slot a stored set, erased (its header 0xFF: also a save cut before its header) or
    headed by the magic (a save or an erase cut short, a damaged set)."""
    if len(data) != IMAGE_SIZE:
        return f"a flash image has {IMAGE_SIZE} bytes"
    for index in range(SLOTS):
        header = data[index * SLOT_SIZE : index * SLOT_SIZE + HEADER.size]
        if header != _ERASED_HEADER and header[: len(MAGIC)] != MAGIC:
            return f"slot {index} holds neither a stored set nor erased flash"
    return None


def _kind(data: bytes) -> str:
    """What a file's first bytes hold, in a word: text or binary data."""
    try:  # (a character cut at the end of ``data`` is no error)
        text = codecs.getincrementaldecoder("utf-8")().decode(data)
    except UnicodeDecodeError:
        return "binary data"
    return "text" if all(c.isprintable() or c.isspace() for c in text) else "binary data"


def _open(path: Path) -> int:
    """A descriptor of ``path`` for reading and writing, created when missing; anything but a
    regular file is refused before it is opened (opening a device may act on it)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise StorageError(f"{path}: cannot open the flash image: {exc}") from None
    for test, kind in _NOT_FILES:
        if mode is not None and test(mode):
            raise StorageError(f"{path}: {kind}, not a flash image file: refused")
    flags = os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOCTTY | os.O_NONBLOCK
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        raise StorageError(f"{path}: cannot open the flash image: {exc}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced since it was looked at
        os.close(fd)
        raise StorageError(f"{path}: not a regular file, not a flash image file: refused")
    return fd


def _holder(fd: int) -> str:
    """Who holds the lock on ``fd``'s file, as /proc/locks says: ``pid N`` (or unknown)."""
    st = os.fstat(fd)
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return "pid unknown"
    for fields in (line.split() for line in lines):
        if len(fields) > 5 and fields[1] == "FLOCK" and fields[5] == key:
            return f"pid {fields[4]}"
    return "pid unknown"


class FlashImage:
    """An ECU's image file, open and locked until :meth:`close` (or until collected); a missing
    or empty file is made an erased image (0xFF) of the full size. Refused with a
    :class:`StorageError` naming the file and why: a file that is not an image (left as it
    is), one another ECU holds, anything but a regular file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fd = _open(path)
        self._close = weakref.finalize(self, os.close, self.fd)  # by close(), or when collected
        try:
            self._lock()
            self._check_or_erase()
        except BaseException:
            self.close()
            raise

    def _lock(self) -> None:
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise StorageError(
                f"{self.path}: another ECU holds this flash image ({_holder(self.fd)}); stop it "
                "or give this ECU another file"
            ) from None
        except OSError as exc:
            raise StorageError(f"{self.path}: cannot lock the flash image: {exc}") from None

    def _check_or_erase(self) -> None:
        try:
            data = os.pread(self.fd, IMAGE_SIZE + 1, 0)
            if not data:
                self.write(0, bytes([ERASED]) * IMAGE_SIZE)
                return
        except OSError as exc:
            raise StorageError(f"{self.path}: cannot open the flash image: {exc}") from None
        why = not_an_image(data)
        if why is not None:
            raise StorageError(
                f"{self.path}: {_kind(data)} of {os.fstat(self.fd).st_size} bytes, not a flash "
                f"image ({why}): refused and left as it is"
            )

    def close(self) -> None:
        """Close the file, which ends the lock (at once; again does nothing)."""
        self._close()

    def __enter__(self) -> FlashImage:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def write(self, offset: int, data: bytes) -> None:
        """One flash operation: ``data`` programmed at ``offset``."""
        os.pwrite(self.fd, data, offset)

    def newest(self) -> Slot | None:
        slots = _slots(os.pread(self.fd, IMAGE_SIZE, 0))
        return max(slots, key=lambda s: s.sequence) if slots else None

    def writer(self, payload: bytes, page_size: int = PAGE_SIZE) -> SlotWriter:
        """A save of ``payload`` into the slot after the newest valid one."""
        if len(payload) > MAX_STORED:
            raise ValueError(f"stored set of {len(payload)} bytes exceeds {MAX_STORED}")
        newest = self.newest()
        index = 0 if newest is None else 1 - newest.index
        sequence = 1 if newest is None else (newest.sequence + 1) & 0xFFFFFFFF
        return SlotWriter(self, index, sequence, payload, page_size)

    def save(self, payload: bytes) -> Slot:
        """A whole save at once (tools, tests and an orderly stop; the ECU at work steps a
        :class:`SlotWriter`)."""
        writer = self.writer(payload)
        while not writer.step():
            pass
        return writer.slot


class SlotWriter:
    """One save as a list of flash operations (erase, pages, header), one per :meth:`step`."""

    def __init__(
        self, flash: FlashImage, index: int, sequence: int, payload: bytes, page_size: int
    ) -> None:
        base = index * SLOT_SIZE
        header = HEADER.pack(MAGIC, sequence, len(payload), _slot_crc(sequence, payload))
        self._ops: list[tuple[int, bytes]] = [(base, bytes([ERASED]) * SLOT_SIZE)]
        for off in range(0, len(payload), page_size):
            self._ops.append((base + HEADER.size + off, payload[off : off + page_size]))
        self._ops.append((base, header))
        self._flash = flash
        self._next = 0
        self.slot = Slot(index, sequence, payload)

    @property
    def operations(self) -> int:
        return len(self._ops)

    def step(self) -> bool:
        """Perform the next operation; True once the save is complete."""
        if self._next < len(self._ops):
            offset, data = self._ops[self._next]
            self._flash.write(offset, data)
            self._next += 1
        return self._next >= len(self._ops)
