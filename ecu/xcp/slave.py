"""The ECU's XCP slave (ASAM MCD-1 XCP 1.x on CAN): a sans-IO command processor.

Classic CAN frames: MAX_CTO = MAX_DTO = 8, Intel byte order, byte address granularity. The
master's command frames come in through :meth:`XcpSlave.receive` (a bounded queue); they are
served at the tick boundary by :meth:`XcpSlave.serve`, and the DAQ lists are sampled after the
tick by :meth:`XcpSlave.sample`. Each hands its frames (responses, errors, events, DTOs) to the
``send(data)`` it is given. So in lockstep a master's requests are served at tick boundaries and
a run with a master attached stays reproducible; in real time the answer comes within one tick.

Bounded work per tick: at most ``MAX_QUEUE`` frames wait (more are dropped and counted), at most
``MAX_FRAMES`` are served in one tick and at most one of them checks a parameter set (a write to
the calibration region: the whole set is checked and compiled), one flash operation of a store
is done, a checksum covers at most ``MAX_CHECKSUM`` bytes, and a DAQ sample sends at most
``daq.MAX_ODTS`` DTOs. Nothing a master sends raises out of the slave: every frame is answered by
a response, an error packet, or (when not connected, or empty) counted and dropped.

Commands: CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID, SET_REQUEST,
GET_SEED, UNLOCK, SET_MTA, UPLOAD, SHORT_UPLOAD, BUILD_CHECKSUM, DOWNLOAD, DOWNLOAD_NEXT (master
block mode), and the dynamic DAQ commands (:mod:`ecu.xcp.daq`) with GET_DAQ_CLOCK; anything else
is ERR_CMD_UNKNOWN.

Protection: after CONNECT the CAL/PAG and DAQ resources are locked; GET_SEED/UNLOCK with the
service port's algorithm (:mod:`ecu.xcp.seed_key`) unlock them for the connection. Reading
(UPLOAD, SHORT_UPLOAD, BUILD_CHECKSUM, GET_ID) needs no unlock; writing (DOWNLOAD, SET_REQUEST)
needs CAL/PAG, DAQ configuration needs DAQ. A stop written to the bench region is always taken.

Writes (DOWNLOAD, or a master block DOWNLOAD + DOWNLOAD_NEXT applied whole when complete):

- CAL/PAG locked: ERR_ACCESS_LOCKED;
- an address outside the map, or not whole values (4-byte aligned, 4-byte multiples):
  ERR_OUT_OF_RANGE;
- a read-only region (measurements, axis points, texts): ERR_WRITE_PROTECTED;
- a parameter outside its limits: ERR_OUT_OF_RANGE;
- a parameter unsafe in RUN, while in RUN: ERR_ACCESS_DENIED;
- the set as a whole refused by the parameter checks (a table that falls or crosses, ...):
  ERR_VERIFY;
- a bench command the ECU's state refuses (an arm in FAULT, a throttle while CAN Demand frames
  are present, ...): ERR_ACCESS_DENIED;
- a tick implementation that takes parameters at power-up only: ERR_ACCESS_DENIED.

An accepted parameter write applies from the next tick. SET_REQUEST with STORE_CAL_REQ saves
the set to flash as the service port's PARAM_SAVE does, one flash operation per tick; the
session status shows STORE_CAL_REQ meanwhile and EV_STORE_CAL says when it is done.
"""

from __future__ import annotations

import random
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from ecu import logbook as L
from ecu import modes as M
from ecu.firmware import Ecu
from ecu.service.bench_control import BenchControl, BenchRefused
from ecu.service.crc import crc16
from ecu.service.param_table import TABLE, ParamTable, WriteRefused
from ecu.service.port import FIRMWARE, Boot, build_id
from ecu.service.storage import SlotWriter
from ecu.xcp import codes as C
from ecu.xcp import daq as D
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import KEY_LENGTH, SEED_LENGTH, key_for

DEFAULT_IDS = (0x700, 0x701)  # master -> ECU, ECU -> master (the DBC's XcpCommand, XcpResponse)
MAX_CTO = 8
MAX_DTO = 8
MAX_BS = 42  # master block mode: 42 frames of 6 bytes, 252 bytes (whole parameters)
MAX_QUEUE = 64  # frames waiting for the next tick
MAX_FRAMES = 48  # frames served per tick
MAX_CHECKSUM = 4096  # bytes per BUILD_CHECKSUM
A2L_NAME = "turbojet_ecu"
PROTOCOL_VERSION = 0x01
TRANSPORT_VERSION = 0x01
DRIVER_VERSION = 0x10
PROTECTED = C.RES_CAL_PAG | C.RES_DAQ
EVENT_100MS = 100  # event 1's cycle, ms

SendFn = Callable[[bytes], None]


# the commands served: command -> (minimum length, the resource it needs, its handler)
COMMANDS: dict[int, tuple[int, int, str]] = {
    C.Cmd.CONNECT: (2, 0, "_connect"),
    C.Cmd.DISCONNECT: (1, 0, "_disconnect"),
    C.Cmd.GET_STATUS: (1, 0, "_get_status"),
    C.Cmd.SYNCH: (1, 0, "_synch"),
    C.Cmd.GET_COMM_MODE_INFO: (1, 0, "_get_comm_mode_info"),
    C.Cmd.GET_ID: (2, 0, "_get_id"),
    C.Cmd.SET_REQUEST: (4, C.RES_CAL_PAG, "_set_request"),
    C.Cmd.GET_SEED: (3, 0, "_get_seed"),
    C.Cmd.UNLOCK: (2, 0, "_unlock"),
    C.Cmd.SET_MTA: (8, 0, "_set_mta"),
    C.Cmd.UPLOAD: (2, 0, "_upload"),
    C.Cmd.SHORT_UPLOAD: (8, 0, "_short_upload"),
    C.Cmd.BUILD_CHECKSUM: (8, 0, "_build_checksum"),
    C.Cmd.DOWNLOAD: (2, 0, "_download"),
    C.Cmd.DOWNLOAD_NEXT: (2, 0, "_download_next"),
    C.Cmd.CLEAR_DAQ_LIST: (4, C.RES_DAQ, "_clear_daq_list"),
    C.Cmd.SET_DAQ_PTR: (6, C.RES_DAQ, "_set_daq_ptr"),
    C.Cmd.WRITE_DAQ: (8, C.RES_DAQ, "_write_daq"),
    C.Cmd.SET_DAQ_LIST_MODE: (8, C.RES_DAQ, "_set_daq_list_mode"),
    C.Cmd.GET_DAQ_LIST_MODE: (4, 0, "_get_daq_list_mode"),
    C.Cmd.START_STOP_DAQ_LIST: (4, C.RES_DAQ, "_start_stop_daq_list"),
    C.Cmd.START_STOP_SYNCH: (2, C.RES_DAQ, "_start_stop_synch"),
    C.Cmd.GET_DAQ_CLOCK: (1, 0, "_get_daq_clock"),
    C.Cmd.READ_DAQ: (1, 0, "_read_daq"),
    C.Cmd.GET_DAQ_PROCESSOR_INFO: (1, 0, "_get_daq_processor_info"),
    C.Cmd.GET_DAQ_RESOLUTION_INFO: (1, 0, "_get_daq_resolution_info"),
    C.Cmd.GET_DAQ_LIST_INFO: (4, 0, "_get_daq_list_info"),
    C.Cmd.GET_DAQ_EVENT_INFO: (4, 0, "_get_daq_event_info"),
    C.Cmd.FREE_DAQ: (1, C.RES_DAQ, "_free_daq"),
    C.Cmd.ALLOC_DAQ: (4, C.RES_DAQ, "_alloc_daq"),
    C.Cmd.ALLOC_ODT: (5, C.RES_DAQ, "_alloc_odt"),
    C.Cmd.ALLOC_ODT_ENTRY: (6, C.RES_DAQ, "_alloc_odt_entry"),
}


class XcpError(Exception):
    """A command refused with an XCP error (``extra``: the error packet's further bytes)."""

    def __init__(self, code: int, message: str = "", extra: bytes = b"") -> None:
        super().__init__(message)
        self.code = code
        self.extra = extra


@dataclass
class Counters:
    frames: int = 0  # command frames received
    served: int = 0  # command frames served
    responses: int = 0
    errors: dict[str, int] = field(default_factory=dict)  # error packets sent, by error name
    ignored: int = 0  # frames while not connected (other than CONNECT)
    empty: int = 0  # frames with no command byte
    queue_overflow: int = 0  # frames dropped: too many waiting
    blocks_aborted: int = 0  # master blocks cut short by another command
    events: int = 0  # EV packets sent
    stores: int = 0  # parameter sets stored to flash
    store_failures: int = 0
    internal_errors: int = 0  # commands that failed inside the slave (ERR_GENERIC)
    ticks: int = 0  # serve + sample cycles
    worst_s: float = 0.0  # the longest serve + sample of a tick
    total_s: float = 0.0

    def refused(self, code: int) -> None:
        name = C.Err(code).name if code in C.Err._value2member_map_ else f"0x{code:02X}"
        self.errors[name] = self.errors.get(name, 0) + 1


def _u16(data: bytes, at: int) -> int:
    return data[at] | data[at + 1] << 8


def _u32(data: bytes, at: int) -> int:
    return struct.unpack_from("<I", data, at)[0]


@dataclass(frozen=True)
class Limits:
    """How much the slave holds: frames waiting, a master block's frames, DAQ lists, ODTs and
    ODT entries. The defaults are this slave's; the C slave (ecu/port/ecu_xcp.c) holds less,
    and a Python slave given its limits answers as it does."""

    max_queue: int = MAX_QUEUE
    max_bs: int = MAX_BS
    max_daq: int = D.MAX_DAQ
    max_odts: int = D.MAX_ODTS
    max_entries: int = D.MAX_ENTRIES


@dataclass
class _Block:
    """A master block download under way: where, how many bytes in all, those received."""

    address: int
    total: int
    data: bytearray


class XcpSlave:
    """The XCP slave of one ECU. ``boot``: the parameter set and flash image (shared with a
    service port, if any); ``bench``: the bench demand source (the service port's, or the
    slave's own); ``clock_us``: the ECU's clock for DAQ timestamps and GET_DAQ_CLOCK (default:
    its ticks times the period, simulated time)."""

    def __init__(
        self,
        ecu: Ecu,
        boot: Boot,
        bench: BenchControl | None = None,
        *,
        ids: tuple[int, int] = DEFAULT_IDS,
        clock_us: Callable[[], int] | None = None,
        seed: int | None = None,
        timer: Callable[[], float] = time.perf_counter,
        limits: Limits | None = None,
    ) -> None:
        self.ecu = ecu
        self.boot = boot
        self.table: ParamTable = boot.table
        self.own_bench = bench is None  # the slave is the demand source's only front end
        self.bench = bench if bench is not None else BenchControl(ecu)
        self.cmd_id, self.res_id = ids
        self.rate_hz = ecu.p.rate_hz
        self._clock_us = clock_us or self._simulated_us
        self._timer = timer
        self._rng = random.Random(seed)
        self.identification = f"{FIRMWARE} build {build_id()}"
        texts = {
            "id": self.identification,
            "a2l": A2L_NAME,
            "a2l_file": f"{A2L_NAME}.a2l",
            "event0": "control tick",
            "event1": "100 ms",
        }
        self.memory = MEM.MemoryMap(ecu, self.table, self.bench, texts)
        self.limits = limits = limits or Limits()
        self.daq = D.Daq(
            self.memory, max_daq=limits.max_daq, max_odts=limits.max_odts,
            max_entries=limits.max_entries,
        )  # fmt: skip
        self.every_100ms = max(1, round(self.rate_hz * EVENT_100MS / 1000))
        self.counters = Counters()
        self._queue: deque[bytes] = deque()
        self.connected = False
        self.locked = PROTECTED
        self.mta = 0
        self._seed: tuple[int, bytes] | None = None  # resource, seed of the unlock under way
        self._key = bytearray()  # key bytes received so far
        self._key_total = 0
        self._block: _Block | None = None
        self._writer: SlotWriter | None = None
        self._send: SendFn = lambda data: None
        self._events_seen = 0
        self._heavy = False  # a parameter set was checked this tick
        self._tick_s = 0.0  # time served so far in this tick
        self._handlers: dict[int, tuple[int, int, Callable[[bytes], bytes | None]]] = {
            command: (minimum, resource, getattr(self, name))
            for command, (minimum, resource, name) in COMMANDS.items()
        }

    # -- the tick boundary ---------------------------------------------------------------------
    def receive(self, data: bytes | bytearray) -> None:
        """A command frame from the bus: queued for the next tick (bounded)."""
        c = self.counters
        c.frames += 1
        if len(self._queue) >= self.limits.max_queue:
            c.queue_overflow += 1
        else:
            self._queue.append(bytes(data))

    def serve(self, send: SendFn) -> None:
        """Serve the frames waiting (at the tick boundary, before the firmware's tick), within
        the tick's budget, and one flash operation of a store under way."""
        queue = self._queue
        if not queue and self._writer is None:
            return  # nothing to do: the usual tick
        t0 = self._timer()
        self._send = send
        self._heavy = False
        for _ in range(min(MAX_FRAMES, len(queue))):
            self._handle(queue.popleft())
            if self._heavy:
                break  # one parameter-set check per tick
        if self._writer is not None:
            self._store_step()
        dt = self._timer() - t0
        self._tick_s += dt
        self.counters.total_s += dt

    def inputs(self, inputs):  # noqa: ANN001, ANN201 (EcuInputs)
        """The inputs the firmware takes this tick, where the slave owns the bench demand
        source (no service port on the node)."""
        return self.bench.step(inputs) if self.own_bench else inputs

    def sample(self, send: SendFn) -> None:
        """After the firmware's tick: the DAQ lists of the events this tick raised (event 0
        every tick, event 1 every 100 ms)."""
        c = self.counters
        c.ticks += 1
        k = self._events_seen
        self._events_seen = k + 1
        if not self.daq.lists or not self.daq.running:
            tick_s = self._tick_s
        else:
            t0 = self._timer()
            self._send = send
            emit = self._emit
            stamp = self._clock_us()
            self.daq.sample(0, stamp, emit)
            if k % self.every_100ms == 0:
                self.daq.sample(1, stamp, emit)
            dt = self._timer() - t0
            c.total_s += dt
            tick_s = self._tick_s + dt  # served and sampled in this tick
        if tick_s:
            self._tick_s = 0.0
            if tick_s > c.worst_s:
                c.worst_s = tick_s

    def _simulated_us(self) -> int:
        return self.ecu.s.ticks * 1_000_000 // self.rate_hz

    def summary(self) -> dict:
        """Counters: frames, refusals by error, DAQ, stores, and the cost per tick (us)."""
        c = self.counters
        ticks = max(c.ticks, 1)
        return {
            "frames": c.frames,
            "served": c.served,
            "responses": c.responses,
            "errors": dict(c.errors),
            "ignored_not_connected": c.ignored,
            "empty_frames": c.empty,
            "queue_overflow": c.queue_overflow,
            "blocks_aborted": c.blocks_aborted,
            "events": c.events,
            "stores": c.stores,
            "store_failures": c.store_failures,
            "internal_errors": c.internal_errors,
            "daq_samples": self.daq.samples,
            "dtos": self.daq.dtos,
            "ticks": c.ticks,
            "worst_us": round(c.worst_s * 1e6, 1),  # serving and sampling, in the worst tick
            "mean_us": round(c.total_s / ticks * 1e6, 2),  # ... per tick, on average
        }

    # -- packets out ---------------------------------------------------------------------------
    def _emit(self, data: bytes) -> None:
        self._send(data)

    def _respond(self, payload: bytes = b"") -> None:
        self.counters.responses += 1
        self._send(bytes((C.PID_RES,)) + payload)

    def _error(self, code: int, extra: bytes = b"") -> None:
        self.counters.refused(code)
        self._send(bytes((C.PID_ERR, code)) + extra)

    def _event(self, code: int) -> None:
        self.counters.events += 1
        self._send(bytes((C.PID_EV, code)))

    # -- commands ------------------------------------------------------------------------------
    def _handle(self, frame: bytes) -> None:
        c = self.counters
        if not frame:
            c.empty += 1
            return
        command = frame[0]
        if not self.connected and command != C.Cmd.CONNECT:
            c.ignored += 1  # a slave not connected answers CONNECT only
            return
        c.served += 1
        if self._block is not None and command != C.Cmd.DOWNLOAD_NEXT:
            self._block = None  # another command ends a block download
            c.blocks_aborted += 1
        entry = self._handlers.get(command)
        if entry is None:
            self._error(C.Err.CMD_UNKNOWN)
            return
        minimum, resource, handler = entry
        if len(frame) < minimum:
            self._error(C.Err.CMD_SYNTAX)
            return
        if resource & self.locked:
            self._error(C.Err.ACCESS_LOCKED)
            return
        try:
            answer = handler(frame)
        except XcpError as exc:
            self._error(exc.code, exc.extra)
        except D.DaqError as exc:
            self._error(exc.code)
        except Exception:  # a fault of the slave's own: the frame is refused, the ECU ticks on
            self.counters.internal_errors += 1
            self._error(C.Err.GENERIC)
        else:
            if answer is not None:
                self._respond(answer)

    def _connect(self, frame: bytes) -> bytes:
        if frame[1] not in (0, 1):  # normal, user defined
            raise XcpError(C.Err.OUT_OF_RANGE, "CONNECT: mode")
        self.connected = True
        self.locked = PROTECTED
        self._seed = None
        self._block = None
        self.daq.stop_all()
        resource = C.RES_CAL_PAG | C.RES_DAQ
        return struct.pack(
            "<BBBHBB", resource, C.COMM_MODE_BASIC_OPTIONAL, MAX_CTO, MAX_DTO, PROTOCOL_VERSION,
            TRANSPORT_VERSION,
        )  # fmt: skip

    def _disconnect(self, frame: bytes) -> bytes:
        self.daq.stop_all()
        self.daq.free()
        self.connected = False
        self.locked = PROTECTED
        self._seed = None
        return b""

    def _get_status(self, frame: bytes) -> bytes:
        session = 0
        if self._writer is not None:
            session |= C.SESSION_STORE_CAL_REQ
        if self.daq.running:
            session |= C.SESSION_DAQ_RUNNING
        return struct.pack("<BBBH", session, self.locked, 0, 0)

    def _synch(self, frame: bytes) -> None:
        raise XcpError(C.Err.CMD_SYNCH)

    def _get_comm_mode_info(self, frame: bytes) -> bytes:
        max_bs = self.limits.max_bs
        return bytes((0, C.COMM_MODE_OPTIONAL_MASTER_BLOCK, 0, max_bs, 0, 0, DRIVER_VERSION))

    def _get_id(self, frame: bytes) -> bytes:
        """Types 0 (ASCII identification), 1 (the A2L's name), 2 (its file name): uploaded
        from the MTA, which points at the text; other types have length 0."""
        key = {C.ID_ASCII: "id", C.ID_A2L_NAME: "a2l", C.ID_A2L_FILE: "a2l_file"}.get(frame[1])
        length = 0
        if key is not None:
            self.mta, length = self.memory.texts.at[key]
        return struct.pack("<BBBI", 0, 0, 0, length)

    def _get_seed(self, frame: bytes) -> bytes:
        mode, resource = frame[1], frame[2]
        if mode == 1:  # the remaining part: the whole seed went in the first
            raise XcpError(C.Err.SEQUENCE, "GET_SEED: the seed fits one frame")
        if mode != 0 or resource not in (C.RES_CAL_PAG, C.RES_DAQ):
            raise XcpError(C.Err.OUT_OF_RANGE, "GET_SEED: mode or resource")
        if not resource & self.locked:
            self._seed = None
            return b"\x00"  # not protected: no seed
        seed = self._rng.getrandbits(8 * SEED_LENGTH).to_bytes(SEED_LENGTH, "big")
        self._seed = (resource, seed)
        self._key = bytearray()
        self._key_total = 0
        return bytes((SEED_LENGTH,)) + seed

    def _unlock(self, frame: bytes) -> bytes:
        if self._seed is None:
            raise XcpError(C.Err.SEQUENCE, "UNLOCK: no seed asked for")
        remaining = frame[1]
        if not self._key:
            self._key_total = remaining
        elif remaining != self._key_total - len(self._key):
            self._seed = None
            raise XcpError(C.Err.SEQUENCE, "UNLOCK: key length")
        self._key += frame[2 : 2 + min(remaining, MAX_CTO - 2)]
        if len(self._key) < self._key_total and len(self._key) < 64:
            return bytes((self.locked,))
        resource, seed = self._seed
        self._seed = None
        if self._key_total != KEY_LENGTH or bytes(self._key) != key_for(seed):
            self.connected = False  # a wrong key ends the session, as the standard says
            self.locked = PROTECTED
            raise XcpError(C.Err.ACCESS_LOCKED, "UNLOCK: wrong key")
        self.locked &= ~resource
        return bytes((self.locked,))

    def _set_mta(self, frame: bytes) -> bytes:
        if frame[3] != 0:
            raise XcpError(C.Err.OUT_OF_RANGE, "address extension")
        self.mta = _u32(frame, 4)
        return b""

    def _read(self, address: int, size: int) -> bytes:
        data = self.memory.read(address, size)
        if data is None:
            raise XcpError(C.Err.OUT_OF_RANGE, f"0x{address:08X}+{size}: not in the map")
        return data

    def _upload(self, frame: bytes) -> bytes:
        size = frame[1]
        if not 1 <= size <= MAX_CTO - 1:
            raise XcpError(C.Err.OUT_OF_RANGE, "UPLOAD: 1..7 bytes (no slave block mode)")
        data = self._read(self.mta, size)
        self.mta += size
        return data

    def _short_upload(self, frame: bytes) -> bytes:
        size = frame[1]
        if not 1 <= size <= MAX_CTO - 1 or frame[3] != 0:
            raise XcpError(C.Err.OUT_OF_RANGE, "SHORT_UPLOAD: 1..7 bytes, extension 0")
        address = _u32(frame, 4)
        data = self._read(address, size)
        self.mta = address + size
        return data

    def _build_checksum(self, frame: bytes) -> bytes:
        size = _u32(frame, 4)
        if not 1 <= size <= MAX_CHECKSUM:
            raise XcpError(C.Err.OUT_OF_RANGE, "block size", struct.pack("<HI", 0, MAX_CHECKSUM))
        data = self._read(self.mta, size)
        self.mta += size
        return struct.pack("<BHI", C.CHECKSUM_CRC_16_CITT, 0, crc16(data))

    # -- writes --------------------------------------------------------------------------------
    def _download(self, frame: bytes) -> bytes | None:
        size = frame[1]
        if size == 0 or size > self.limits.max_bs * (MAX_CTO - 2):
            raise XcpError(C.Err.OUT_OF_RANGE, "DOWNLOAD: 1..252 bytes")
        part = min(size, MAX_CTO - 2)
        if len(frame) < 2 + part:
            raise XcpError(C.Err.CMD_SYNTAX, "DOWNLOAD: fewer data bytes than its length")
        data = bytearray(frame[2 : 2 + part])
        if size > part:  # a master block: the rest comes in DOWNLOAD_NEXT frames
            self._block = _Block(self.mta, size, data)
            return None
        return self._write(self.mta, bytes(data))

    def _download_next(self, frame: bytes) -> bytes | None:
        block = self._block
        if block is None:
            raise XcpError(C.Err.SEQUENCE, "DOWNLOAD_NEXT: no block under way", b"\x00")
        remaining = block.total - len(block.data)
        if frame[1] != remaining:
            self._block = None
            raise XcpError(C.Err.SEQUENCE, "DOWNLOAD_NEXT: count", bytes((remaining,)))
        part = min(remaining, MAX_CTO - 2)
        if len(frame) < 2 + part:
            self._block = None
            raise XcpError(C.Err.CMD_SYNTAX, "DOWNLOAD_NEXT: fewer data bytes than its count")
        block.data += frame[2 : 2 + part]
        if len(block.data) < block.total:
            return None
        self._block = None
        return self._write(block.address, bytes(block.data))

    def _write(self, address: int, data: bytes) -> bytes:
        """Write ``data`` at ``address`` (whole, or refused whole); the MTA moves past it."""
        region = self.memory.locate(address, len(data))
        if region is None:
            raise XcpError(C.Err.OUT_OF_RANGE, f"0x{address:08X}: not in the map")
        if not region.writable:
            raise XcpError(C.Err.WRITE_PROTECTED, f"{region.name}: read only")
        offset = address - region.base
        if offset % MEM.WORD or len(data) % MEM.WORD:
            raise XcpError(C.Err.OUT_OF_RANGE, "writes cover whole 4-byte values")
        words = struct.unpack(f"<{len(data) // MEM.WORD}i", data)
        first = offset // MEM.WORD
        if region is self.memory.calibration:
            self._write_parameters(first, words)
        else:
            self._write_bench(first, words)
        self.mta = address + len(data)
        return b""

    def _write_parameters(self, first: int, words: tuple[int, ...]) -> None:
        if self.locked & C.RES_CAL_PAG:
            raise XcpError(C.Err.ACCESS_LOCKED, "CAL/PAG locked")
        if not isinstance(self.ecu, Ecu):
            raise XcpError(C.Err.ACCESS_DENIED, "parameters at power-up only")
        raws = self.table.raws()
        writes = [
            (TABLE[first + k].name, raw) for k, raw in enumerate(words) if raw != raws[first + k]
        ]
        if not writes:
            return
        self._heavy = True
        try:
            params, firmware = self.table.check_writes(writes, self.ecu.out.mode == M.RUN)
        except WriteRefused as exc:
            code = {"OUT_OF_RANGE": C.Err.OUT_OF_RANGE, "REFUSED_IN_RUN": C.Err.ACCESS_DENIED}
            raise XcpError(code.get(exc.reason, C.Err.VERIFY), str(exc)) from None
        self.table.commit(params, firmware)
        self.ecu.p = firmware  # applies from the next tick

    def _write_bench(self, first: int, words: tuple[int, ...]) -> None:
        bench = self.bench
        for k, value in enumerate(words, first):
            if k == MEM.BENCH_STOP:
                if value:
                    bench.stop()  # always accepted
                continue
            if self.locked & C.RES_CAL_PAG:
                raise XcpError(C.Err.ACCESS_LOCKED, "CAL/PAG locked")
            try:
                if k == MEM.BENCH_ARM:
                    if value not in (0, 1):
                        raise XcpError(C.Err.OUT_OF_RANGE, "bench_arm: 1 arms, 0 does nothing")
                    if value:
                        bench.arm()
                elif k == MEM.BENCH_THROTTLE:
                    bench.throttle(value / 100)
                elif k == MEM.BENCH_TEST_LEVEL:
                    bench.set_test(level=value)
                elif k == MEM.BENCH_TEST_MS:
                    bench.set_test(ms=value)
                else:
                    bench.test(value)
            except BenchRefused as exc:
                code = C.Err.OUT_OF_RANGE if exc.reason == "OUT_OF_RANGE" else C.Err.ACCESS_DENIED
                raise XcpError(code, str(exc)) from None

    def _set_request(self, frame: bytes) -> bytes:
        mode = frame[1]
        if mode & ~C.REQUEST_STORE_CAL:
            raise XcpError(C.Err.OUT_OF_RANGE, "SET_REQUEST: only STORE_CAL_REQ")
        if not mode:
            return b""
        flash = self.boot.flash
        if flash is None:
            raise XcpError(C.Err.ACCESS_DENIED, "no flash image (start the ECU with --flash)")
        if self.boot.saving is not None:
            raise XcpError(C.Err.CMD_BUSY, "a save is in progress")
        try:
            self._writer = flash.writer(self.table.stored_image(L.stored_dict(self.ecu.s)))
        except OSError as exc:
            raise XcpError(C.Err.ACCESS_DENIED, f"flash image unreadable: {exc}") from None
        self.boot.saving = self
        return b""

    def _store_step(self) -> None:
        """One flash operation of the store under way; EV_STORE_CAL once it is done."""
        assert self._writer is not None
        try:
            done = self._writer.step()
        except OSError:
            self.counters.store_failures += 1
            self._writer = self.boot.saving = None
            return
        if not done:
            return
        slot = self._writer.slot
        b = self.boot
        b.state, b.slot, b.sequence = "loaded", slot.index, slot.sequence
        self._writer = b.saving = None
        self.counters.stores += 1
        self._event(C.Ev.STORE_CAL)

    # -- DAQ -----------------------------------------------------------------------------------
    def _get_daq_processor_info(self, frame: bytes) -> bytes:
        properties = C.DAQ_PROPERTY_DYNAMIC | C.DAQ_PROPERTY_PRESCALER | C.DAQ_PROPERTY_TIMESTAMP
        return struct.pack("<BHHBB", properties, self.daq.max_daq, D.EVENTS, 0, 0)

    def _get_daq_resolution_info(self, frame: bytes) -> bytes:
        return struct.pack("<BBBBBH", 1, D.MAX_ENTRY_SIZE, 1, 0, C.TIMESTAMP_MODE, 1)

    def _get_daq_event_info(self, frame: bytes) -> bytes:
        event = _u16(frame, 2)
        if event >= D.EVENTS:
            raise XcpError(C.Err.OUT_OF_RANGE, f"event {event}")
        self.mta, length = self.memory.texts.at[f"event{event}"]
        cycle_ms = 1000 // self.rate_hz if event == 0 else EVENT_100MS
        properties = C.EVENT_PROPERTY_DAQ | C.EVENT_CONSISTENCY_EVENT
        return bytes((properties, 0xFF, length, cycle_ms, C.UNIT_1MS, 1 - event))

    def _get_daq_list_info(self, frame: bytes) -> bytes:
        daq = self.daq.mode_of(_u16(frame, 2))
        return struct.pack("<BBBH", 0x04, len(daq.odts), D.MAX_ODT_BYTES, 0xFFFF)

    def _free_daq(self, frame: bytes) -> bytes:
        self.daq.free()
        return b""

    def _alloc_daq(self, frame: bytes) -> bytes:
        self.daq.alloc_daq(_u16(frame, 2))
        return b""

    def _alloc_odt(self, frame: bytes) -> bytes:
        self.daq.alloc_odt(_u16(frame, 2), frame[4])
        return b""

    def _alloc_odt_entry(self, frame: bytes) -> bytes:
        self.daq.alloc_entries(_u16(frame, 2), frame[4], frame[5])
        return b""

    def _set_daq_ptr(self, frame: bytes) -> bytes:
        self.daq.set_ptr(_u16(frame, 2), frame[4], frame[5])
        return b""

    def _write_daq(self, frame: bytes) -> bytes:
        self.daq.write(frame[1], frame[2], frame[3], _u32(frame, 4))
        return b""

    def _read_daq(self, frame: bytes) -> bytes:
        bit_offset, size, address = self.daq.read()
        return struct.pack("<BBBI", bit_offset, size, 0, address)

    def _clear_daq_list(self, frame: bytes) -> bytes:
        daq = self.daq.mode_of(_u16(frame, 2))
        daq.running = daq.selected = False
        for odt in daq.odts:
            for e in odt:
                e.size = 0
        return b""

    def _set_daq_list_mode(self, frame: bytes) -> bytes:
        self.daq.set_mode(frame[1], _u16(frame, 2), _u16(frame, 4), frame[6], frame[7])
        return b""

    def _get_daq_list_mode(self, frame: bytes) -> bytes:
        daq = self.daq.mode_of(_u16(frame, 2))
        mode = (daq.mode & C.DAQ_MODE_TIMESTAMP) | C.DAQ_MODE_TIMESTAMP
        mode |= (C.DAQ_MODE_RUNNING if daq.running else 0) | (1 if daq.selected else 0)
        return struct.pack("<BHHBB", mode, 0, daq.event, daq.prescaler, daq.priority)

    def _start_stop_daq_list(self, frame: bytes) -> bytes:
        return bytes((self.daq.start_stop(frame[1], _u16(frame, 2)),))

    def _start_stop_synch(self, frame: bytes) -> bytes:
        self.daq.synch(frame[1])
        return b""

    def _get_daq_clock(self, frame: bytes) -> bytes:
        return struct.pack("<BBBI", 0, 0, 0, self._clock_us() & 0xFFFFFFFF)
