"""Dynamic DAQ lists: what a master allocates and fills (FREE_DAQ, ALLOC_DAQ, ALLOC_ODT,
ALLOC_ODT_ENTRY, SET_DAQ_PTR, WRITE_DAQ, SET_DAQ_LIST_MODE), started and stopped
(START_STOP_DAQ_LIST, START_STOP_SYNCH), and sampled on the slave's event channels.

Every ODT goes out as one DTO: its absolute ODT number (the PID, FIRST_PID of its list plus its
number in the list), on the first ODT of a sample the 4-byte timestamp (always: TIMESTAMP_FIXED),
then its entries' bytes. An ODT therefore holds at most 7 bytes, the first of a list at most 3.
The entries of all lists sampled on one event come from the same image of the memory, taken
after the tick (consistency per event channel). Allocation is bounded (:data:`MAX_DAQ`,
:data:`MAX_ODTS`, :data:`MAX_ENTRIES`), so that a sample of every list costs at most
``MAX_ODTS`` frames; beyond, ERR_MEMORY_OVERFLOW.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from ecu.xcp import codes as C
from ecu.xcp.memory import MemoryMap

MAX_DAQ = 16  # DAQ lists
MAX_ODTS = 64  # ODTs of all lists together: at most this many DTOs per event
MAX_ENTRIES = 256  # ODT entries of all lists together
MAX_ODT_BYTES = 7  # MAX_DTO - the PID
MAX_ENTRY_SIZE = 7
EVENTS = 2  # 0: the control tick, 1: 100 ms

_TS = struct.Struct("<I")

# allocation phases: what may come next (ERR_SEQUENCE otherwise)
FREED, DAQ_ALLOCATED, ODT_ALLOCATED, ENTRY_ALLOCATED = range(4)


class DaqError(Exception):
    """A DAQ command refused: ``code`` is the XCP error."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


class Entry:
    __slots__ = ("address", "size", "image", "start")

    def __init__(self) -> None:
        self.address = 0
        self.size = 0  # 0: not written
        self.image: Callable[[], bytes | bytearray] | None = None
        self.start = 0


class DaqList:
    __slots__ = (
        "odts", "first_pid", "mode", "event", "prescaler", "priority", "selected", "running",
        "count", "mode_set",
    )  # fmt: skip

    def __init__(self) -> None:
        self.odts: list[list[Entry]] = []
        self.first_pid = 0
        self.mode = 0
        self.event = 0
        self.prescaler = 1
        self.priority = 0
        self.selected = False
        self.running = False
        self.count = 0  # events seen since started (for the prescaler)
        self.mode_set = False


class Daq:
    """The DAQ lists of one slave over its memory map; at most ``max_daq`` lists, ``max_odts``
    ODTs and ``max_entries`` ODT entries in all (a slave with less memory allocates less)."""

    def __init__(
        self,
        memory: MemoryMap,
        *,
        max_daq: int = MAX_DAQ,
        max_odts: int = MAX_ODTS,
        max_entries: int = MAX_ENTRIES,
    ) -> None:
        self.memory = memory
        self.max_daq = max_daq
        self.max_odts = max_odts
        self.max_entries = max_entries
        self.lists: list[DaqList] = []
        self.phase = FREED
        self.ptr: tuple[int, int, int] | None = None  # list, ODT, entry of the next WRITE_DAQ
        self.odts = 0
        self.entries = 0
        self.samples = 0  # lists sampled
        self.dtos = 0  # DTOs sent

    @property
    def running(self) -> bool:
        return any(d.running for d in self.lists)

    def _list(self, number: int) -> DaqList:
        if not 0 <= number < len(self.lists):
            raise DaqError(C.Err.OUT_OF_RANGE, f"DAQ list {number}: {len(self.lists)} allocated")
        return self.lists[number]

    # -- allocation ------------------------------------------------------------------------
    def free(self) -> None:
        self.lists.clear()
        self.phase = FREED
        self.ptr = None
        self.odts = self.entries = 0

    def alloc_daq(self, count: int) -> None:
        if self.phase not in (FREED, DAQ_ALLOCATED) or self.lists:
            raise DaqError(C.Err.SEQUENCE, "ALLOC_DAQ: only once after FREE_DAQ")
        if count > self.max_daq:
            raise DaqError(C.Err.MEMORY_OVERFLOW, f"ALLOC_DAQ {count}: at most {self.max_daq}")
        self.lists = [DaqList() for _ in range(count)]
        self.phase = DAQ_ALLOCATED

    def alloc_odt(self, number: int, count: int) -> None:
        if self.phase not in (DAQ_ALLOCATED, ODT_ALLOCATED):
            raise DaqError(C.Err.SEQUENCE, "ALLOC_ODT: after ALLOC_DAQ, before ALLOC_ODT_ENTRY")
        daq = self._list(number)
        if daq.odts:
            raise DaqError(C.Err.SEQUENCE, f"ALLOC_ODT: DAQ list {number} has its ODTs")
        if self.odts + count > self.max_odts:
            raise DaqError(C.Err.MEMORY_OVERFLOW, f"ALLOC_ODT: at most {self.max_odts} ODTs")
        daq.odts = [[] for _ in range(count)]
        self.odts += count
        first = 0
        for d in self.lists:  # absolute ODT numbers: the lists' ODTs one after the other
            d.first_pid = first
            first += len(d.odts)
        self.phase = ODT_ALLOCATED

    def alloc_entries(self, number: int, odt: int, count: int) -> None:
        if self.phase not in (ODT_ALLOCATED, ENTRY_ALLOCATED):
            raise DaqError(C.Err.SEQUENCE, "ALLOC_ODT_ENTRY: after ALLOC_ODT")
        daq = self._list(number)
        if not 0 <= odt < len(daq.odts):
            raise DaqError(C.Err.OUT_OF_RANGE, f"ODT {odt} of DAQ list {number}: not allocated")
        if daq.odts[odt]:
            raise DaqError(C.Err.SEQUENCE, f"ALLOC_ODT_ENTRY: ODT {odt} has its entries")
        if count > MAX_ODT_BYTES:
            raise DaqError(C.Err.MEMORY_OVERFLOW, f"ALLOC_ODT_ENTRY {count}: at most 7 per ODT")
        if self.entries + count > self.max_entries:
            raise DaqError(C.Err.MEMORY_OVERFLOW, f"at most {self.max_entries} ODT entries")
        daq.odts[odt] = [Entry() for _ in range(count)]
        self.entries += count
        self.phase = ENTRY_ALLOCATED

    # -- configuration -----------------------------------------------------------------------
    def set_ptr(self, number: int, odt: int, entry: int) -> None:
        daq = self._list(number)
        if daq.running:
            raise DaqError(C.Err.DAQ_ACTIVE, f"DAQ list {number} is running")
        if not 0 <= odt < len(daq.odts) or not 0 <= entry < len(daq.odts[odt]):
            raise DaqError(C.Err.OUT_OF_RANGE, f"ODT {odt} entry {entry} of list {number}")
        self.ptr = (number, odt, entry)

    def write(self, bit_offset: int, size: int, ext: int, address: int) -> None:
        if self.ptr is None:
            raise DaqError(C.Err.SEQUENCE, "WRITE_DAQ: no DAQ pointer (SET_DAQ_PTR)")
        number, odt, entry = self.ptr
        daq = self.lists[number]
        if daq.running:
            raise DaqError(C.Err.DAQ_ACTIVE, f"DAQ list {number} is running")
        if bit_offset != 0xFF:
            raise DaqError(C.Err.OUT_OF_RANGE, "WRITE_DAQ: bit offsets are not supported")
        if ext != 0 or not 1 <= size <= MAX_ENTRY_SIZE:
            raise DaqError(C.Err.OUT_OF_RANGE, f"WRITE_DAQ: size {size}, extension {ext}")
        region = self.memory.locate(address, size)
        if region is None:
            raise DaqError(C.Err.OUT_OF_RANGE, f"WRITE_DAQ: 0x{address:08X} is not in the map")
        entries = daq.odts[odt]
        used = sum(e.size for k, e in enumerate(entries) if k != entry)
        if used + size > MAX_ODT_BYTES:
            raise DaqError(C.Err.DAQ_CONFIG, f"ODT {odt} of list {number}: over 7 bytes")
        e = entries[entry]
        e.address, e.size, e.image, e.start = address, size, region.image, address - region.base
        self.ptr = (number, odt, entry + 1) if entry + 1 < len(entries) else None

    def read(self) -> tuple[int, int, int]:
        """READ_DAQ: (bit offset, size, address) of the entry at the pointer, which advances."""
        if self.ptr is None:
            raise DaqError(C.Err.SEQUENCE, "READ_DAQ: no DAQ pointer (SET_DAQ_PTR)")
        number, odt, entry = self.ptr
        entries = self.lists[number].odts[odt]
        e = entries[entry]
        self.ptr = (number, odt, entry + 1) if entry + 1 < len(entries) else None
        return 0xFF, e.size, e.address

    def set_mode(self, mode: int, number: int, event: int, prescaler: int, priority: int) -> None:
        daq = self._list(number)
        if daq.running:
            raise DaqError(C.Err.DAQ_ACTIVE, f"DAQ list {number} is running")
        unsupported = C.DAQ_MODE_ALTERNATING | C.DAQ_MODE_DIRECTION_STIM | C.DAQ_MODE_DTO_CTR
        if mode & (unsupported | C.DAQ_MODE_PID_OFF):
            raise DaqError(C.Err.OUT_OF_RANGE, f"SET_DAQ_LIST_MODE: mode 0x{mode:02X}")
        if not 0 <= event < EVENTS or prescaler < 1:
            raise DaqError(C.Err.OUT_OF_RANGE, f"event {event}, prescaler {prescaler}")
        daq.mode, daq.event, daq.prescaler, daq.priority = mode, event, prescaler, priority
        daq.mode_set = True

    def mode_of(self, number: int) -> DaqList:
        return self._list(number)

    def _check_ready(self, number: int, daq: DaqList) -> None:
        """A list may start once it has ODTs, its mode, and every entry written, and its first
        ODT leaves room for the timestamp."""
        if not daq.odts or not daq.mode_set:
            raise DaqError(C.Err.DAQ_CONFIG, f"DAQ list {number}: no ODTs or no mode")
        for odt in daq.odts:
            if any(e.size == 0 for e in odt):
                raise DaqError(C.Err.DAQ_CONFIG, f"DAQ list {number}: entries not written")
        if sum(e.size for e in daq.odts[0]) + C.TIMESTAMP_SIZE > MAX_ODT_BYTES:
            raise DaqError(C.Err.DAQ_CONFIG, f"DAQ list {number}: no room for the timestamp")

    def start_stop(self, mode: int, number: int) -> int:
        """START_STOP_DAQ_LIST: 0 stop, 1 start, 2 select; returns the list's FIRST_PID."""
        daq = self._list(number)
        if mode == 0:
            daq.running = daq.selected = False
        elif mode in (1, 2):
            self._check_ready(number, daq)
            if mode == 1:
                daq.running, daq.count = True, 0
            else:
                daq.selected = True
        else:
            raise DaqError(C.Err.OUT_OF_RANGE, f"START_STOP_DAQ_LIST: mode {mode}")
        return daq.first_pid

    def synch(self, mode: int) -> None:
        """START_STOP_SYNCH: 0 stop all, 1 start the selected, 2 stop the selected."""
        if mode == 0:
            for d in self.lists:
                d.running = d.selected = False
        elif mode == 1:
            for d in self.lists:
                if d.selected:
                    d.running, d.selected, d.count = True, False, 0
        elif mode == 2:
            for d in self.lists:
                if d.selected:
                    d.running = d.selected = False
        else:
            raise DaqError(C.Err.OUT_OF_RANGE, f"START_STOP_SYNCH: mode {mode}")

    def stop_all(self) -> None:
        for d in self.lists:
            d.running = d.selected = False

    # -- sampling --------------------------------------------------------------------------
    def sample(self, event: int, timestamp_us: int, send: Callable[[bytes], None]) -> None:
        """The event happened: every running list on it, due by its prescaler, goes out."""
        stamp = _TS.pack(timestamp_us & 0xFFFFFFFF)
        images: dict[int, bytes | bytearray] = {}
        for daq in self.lists:
            if not daq.running or daq.event != event:
                continue
            due = daq.count % daq.prescaler == 0
            daq.count += 1
            if not due:
                continue
            self.samples += 1
            pid = daq.first_pid
            for j, odt in enumerate(daq.odts):
                dto = bytearray((pid + j,))
                if j == 0:
                    dto += stamp
                for e in odt:
                    key = id(e.image)
                    image = images.get(key)
                    if image is None:
                        image = images[key] = e.image()  # type: ignore[misc]
                    dto += image[e.start : e.start + e.size]
                send(bytes(dto))
                self.dtos += 1
