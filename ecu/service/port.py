"""The ECU side of the service port, serviced once per control tick within a fixed budget.

:meth:`ServicePort.poll` runs before each firmware tick, as a microcontroller's main loop would
run its UART task: it reads at most ``MAX_RX_BYTES`` without waiting, handles at most
``MAX_REQUESTS`` requests (further decoded ones wait in a short queue, beyond which they are
dropped and counted), records rising fault bits in the fault log, queues a live-data sample when
the stream is due, performs at most one flash operation of a parameter save, and hands at most
``MAX_TX_BYTES`` to the line, which takes what it can without blocking. Frames that do not fit the
transmit buffer are dropped and counted (stream samples first: they are never queued past half
the buffer). The time each poll takes is measured: ``worst_s`` is the longest in wall time (it
includes any preemption by the operating system), ``worst_cpu_s`` the most CPU time.

Writes, saves, clearing the log, arming and the throttle need an unlocked session: the tool asks
for a seed and answers with :func:`ecu.service.message.unlock_key`; the session lasts
``SESSION_S`` of ECU time after the last request. A stop request is always accepted and holds
the stop input until an arm request (or a power cycle). Arm and throttle make the port the demand
source while no CAN Demand is present (:mod:`ecu.service.bench_demand`); while one is, an arm
only releases a held stop and the throttle is refused. An arm the firmware would not take (no
valid readings yet, a latched FAULT, a cool-down under way) is refused with the reason. A
request repeated with the same sequence number and service (the client's retry after a lost
answer) is answered again without being run twice.
"""

from __future__ import annotations

import hashlib
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

from ecu import logbook as L
from ecu import modes as M
from ecu.firmware import Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.service import bench_demand as BD
from ecu.service import fault_log as FL
from ecu.service import live
from ecu.service.bench_control import BenchControl, BenchRefused
from ecu.service.framing import FrameDecoder, encode_frame
from ecu.service.message import (
    VERSION,
    Kind,
    Message,
    MessageError,
    Service,
    Status,
    pack,
    unlock_key,
    unpack,
)
from ecu.service.param_table import TABLE, ParamTable, WriteRefused
from ecu.service.storage import FlashImage, SlotWriter
from ecu.service.transport import Transport

FIRMWARE = "turbojet-ecu 0.1"
MAX_RX_BYTES = 512  # read per tick
MAX_REQUESTS = 4  # handled per tick
PENDING_MAX = 16  # decoded requests waiting for a later tick
TX_BUFFER = 4096  # bytes of frames waiting for the line
MAX_TX_BYTES = 1024  # handed to the line per tick
SESSION_S = 10.0
FAULT_PAGE = 3  # fault-log entries per response (with extreme values, one fits a frame)
ERROR_MAX_BYTES = 200  # of an error text: with the header and map it fits a frame
MIN_STREAM_HZ = 0.1
REPEAT_S = 2.0  # a request repeated (same sequence and service) within this is not run again
# the COUNTERS response: its values in this order
COUNTER_NAMES = (
    "rx_bytes", "tx_bytes", "frames", "malformed", "crc_errors", "oversized", "bad_messages",
    "unexpected", "requests", "repeats", "queue_overflow", "tx_dropped", "stream_samples", "polls",
    "worst_us", "worst_cpu_us", "mean_us", "mean_cpu_us",
)  # fmt: skip


@cache
def build_id() -> str:
    """The firmware build: a digest of the ECU's sources (the same sources give the same id)."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parents[1].glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:12]


@dataclass
class Boot:
    """The parameter set the ECU powers up with, and where it came from."""

    table: ParamTable
    flash: FlashImage | None = None
    state: str = "none"  # none (no flash image), loaded, defaults (no valid slot)
    slot: int | None = None
    sequence: int | None = None
    problems: list[str] = field(default_factory=list)
    saving: object | None = None  # who is saving the set to flash (one save at a time)
    payload: bytes | None = None  # the stored set loaded (its logbook: ecu.service.logbook_save)


def boot(params: EcuParams, flash_path: Path | None) -> Boot:
    """Load the newest valid slot of the flash image over ``params``; defaults when none is."""
    table = ParamTable(params)
    if flash_path is None:
        return Boot(table)
    flash = FlashImage(flash_path)
    slot = flash.newest()
    if slot is None:
        return Boot(table, flash, "defaults")
    problems = table.load_image(slot.payload)
    return Boot(table, flash, "loaded", slot.index, slot.sequence, problems, payload=slot.payload)


class ServiceError(Exception):
    def __init__(self, status: Status, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass
class Counters:
    rx_bytes: int = 0
    tx_bytes: int = 0
    requests: int = 0
    bad_messages: int = 0  # frames whose payload is not a message
    unexpected: int = 0  # messages that are not requests
    queue_overflow: int = 0  # requests dropped: too many waiting
    repeats: int = 0  # requests repeated by the client: answered again, not run again
    tx_dropped: int = 0  # frames dropped: the transmit buffer was full
    stream_samples: int = 0
    polls: int = 0
    worst_s: float = 0.0  # wall time of the longest poll (includes preemption by the OS)
    worst_cpu_s: float = 0.0  # this thread's CPU time in the longest-computing poll
    total_s: float = 0.0
    total_cpu_s: float = 0.0


def _arg(body: Any, name: str, kind: type | tuple[type, ...], default: Any = None) -> Any:
    """A request's field, checked: BAD_REQUEST naming the field when missing or mistyped."""
    value = body.get(name, default) if isinstance(body, dict) else default
    if isinstance(value, bool) or not isinstance(value, kind):
        what = "number" if isinstance(kind, tuple) else kind.__name__
        raise ServiceError(Status.BAD_REQUEST, f"field '{name}' must be a {what}")
    return value


class ServicePort:
    def __init__(
        self,
        transport: Transport,
        ecu: Ecu,
        boot_state: Boot,
        *,
        seed: int | None = None,
        clock: Callable[[], float] = time.perf_counter,
        cpu_clock: Callable[[], float] = time.thread_time,
    ) -> None:
        self.transport = transport
        self.ecu = ecu
        self.boot = boot_state
        self.table = boot_state.table
        self.rate_hz = ecu.p.rate_hz
        self.decoder = FrameDecoder()
        self.counters = Counters()
        self.fault_log = FL.FaultLog()
        self._clock = clock
        self._cpu_clock = cpu_clock
        self._build = build_id()  # at power-up, not inside a tick
        self._rng = random.Random(seed)
        self._pending: deque[bytes] = deque()
        self._tx = bytearray()
        self._stream_every = 0
        self._stream_seq = 0
        self._seed: int | None = None
        self._session_until = -1  # poll count until which the session is unlocked
        self._writer: SlotWriter | None = None
        self._save_request: Message | None = None
        self._last_request: tuple[int, int] | None = None  # (sequence, service) last handled
        self._last_answer: bytes | None = None  # its response frame (None while pending)
        self._last_until = 0  # poll count until which a repeat of it gets that answer again
        self._handlers: dict[int, Callable[[Any], Any]] = {
            Service.IDENTIFY: self._identify,
            Service.STREAM: self._stream,
            Service.COUNTERS: self._counters,
            Service.PARAM_INFO: self._param_info,
            Service.PARAM_READ: self._param_read,
            Service.PARAM_WRITE: self._param_write,
            Service.PARAM_SAVE: self._param_save,
            Service.FAULT_LOG_READ: self._fault_log_read,
            Service.FAULT_LOG_CLEAR: self._fault_log_clear,
            Service.LOGBOOK_READ: self._logbook_read,
            Service.UNLOCK_SEED: self._unlock_seed,
            Service.UNLOCK_KEY: self._unlock_key,
            Service.ARM: self._arm,
            Service.STOP: self._stop,
            Service.THROTTLE: self._throttle,
        }
        # the bench demand source (arm, throttle, stop), shared with an XCP slave on the node
        self.bench_control = BenchControl(ecu, self._log_source)
        self.bench = self.bench_control.demand
        snapshot = self._snapshot()
        if boot_state.state == "defaults":
            self.fault_log.record(0, FL.PARAMS_DEFAULTS, snapshot)
        if boot_state.problems:
            self.fault_log.record(0, FL.PARAMS_REJECTED, snapshot)

    # -- the per-tick task -------------------------------------------------------------------
    def poll(self, inputs: EcuInputs, ticking: bool = True) -> EcuInputs:
        """Service the port once, before the firmware tick that takes ``inputs``; returns the
        inputs the tick takes (with the bench's demand while the port is the demand source).
        With ``ticking`` False between no ticks (the engine stopped: a lockstep ECU with no
        plant yet), requests are answered but no live sample is due and the poll is not
        counted."""
        t0 = self._clock()
        cpu0 = self._cpu_clock()
        c = self.counters
        data = self.transport.read(MAX_RX_BYTES)
        if data:
            c.rx_bytes += len(data)
            for payload in self.decoder.feed(data):
                if len(self._pending) < PENDING_MAX:
                    self._pending.append(payload)
                else:
                    c.queue_overflow += 1
        for _ in range(min(MAX_REQUESTS, len(self._pending))):
            if self._handle(self._pending.popleft()) == Service.PARAM_WRITE:
                break  # a write recompiles the parameters: the only one this tick
        ecu = self.ecu
        ticked = self.bench_control.step(inputs, ticking)
        self.fault_log.update(ecu.s.ticks, ecu.out.fault_word, self._snapshot(), ecu.out.seq_reason)
        if ticking and self._stream_every and c.polls % self._stream_every == 0:
            self._send_stream()
        if self._writer is not None:
            self._flash_step()
        if self._tx:
            n = self.transport.write(bytes(self._tx[:MAX_TX_BYTES]))
            del self._tx[:n]
            c.tx_bytes += n
        if not ticking:
            return inputs
        c.polls += 1
        dt = self._clock() - t0
        cpu = self._cpu_clock() - cpu0
        c.total_s += dt
        c.total_cpu_s += cpu
        if dt > c.worst_s:
            c.worst_s = dt
        if cpu > c.worst_cpu_s:
            c.worst_cpu_s = cpu
        return ticked

    def note_other_ecu(self) -> None:
        """Another ECU heard on the bus (:meth:`ecu.node.EcuNode.watch_bus`): in the fault log."""
        self.fault_log.record(self.ecu.s.ticks, FL.OTHER_ECU, self._snapshot())

    def _log_source(self, source: int) -> None:
        code = FL.DEMAND_SOURCE_CAN if source == BD.CAN else FL.DEMAND_SOURCE_BENCH
        self.fault_log.record(self.ecu.s.ticks, code, self._snapshot())

    def _snapshot(self) -> tuple[int, ...]:
        o = self.ecu.out
        s = self.ecu.s
        return (
            o.mode, o.fault_word, o.n_cpct, s.egt_dk, o.pump_mv, s.supply_mv, s.pump_ma,
            o.seq_state,
        )  # fmt: skip

    # -- frames out --------------------------------------------------------------------------
    def _queue(self, frame: bytes, limit: int = TX_BUFFER) -> None:
        if len(self._tx) + len(frame) > limit:
            self.counters.tx_dropped += 1
        else:
            self._tx += frame

    def _refuse(self, request: Message, status: Status, why: str) -> None:
        """An error response; the text is cut to fit a frame (it may quote the request)."""
        text = why.encode()[:ERROR_MAX_BYTES].decode(errors="ignore")
        self._respond(request, status, {"error": text})

    def _respond(self, request: Message, status: Status, body: Any) -> None:
        frame = encode_frame(
            pack(Message(Kind.RESPONSE, request.seq, request.service, status, body))
        )
        if (request.seq, request.service) == self._last_request:
            self._last_answer = frame  # kept for a repeat of the request
        self._queue(frame)

    def _send_stream(self) -> None:
        self._stream_seq = (self._stream_seq + 1) & 0xFFFF
        msg = Message(
            Kind.STREAM,
            self._stream_seq,
            Service.STREAM,
            Status.OK,
            live.sample(self.ecu, self.bench.source),
        )
        self._queue(encode_frame(pack(msg)), TX_BUFFER // 2)
        self.counters.stream_samples += 1

    # -- requests ----------------------------------------------------------------------------
    def _handle(self, payload: bytes) -> int | None:
        """Answer one request; returns its service (None for what is not a request)."""
        c = self.counters
        try:
            msg = unpack(payload)
        except MessageError:
            c.bad_messages += 1
            return None
        if msg.kind != Kind.REQUEST:
            c.unexpected += 1
            return None
        c.requests += 1
        key = (msg.seq, msg.service)
        if key == self._last_request and c.polls < self._last_until:
            c.repeats += 1  # the client did not hear the answer and asked again: answer again
            if self._last_answer is not None:
                self._queue(self._last_answer)
            return msg.service
        self._last_request, self._last_answer = key, None
        self._last_until = c.polls + round(REPEAT_S * self.rate_hz)
        handler = self._handlers.get(msg.service)
        if msg.version != VERSION:
            why = f"protocol version {msg.version} not supported (this ECU: {VERSION})"
            self._refuse(msg, Status.BAD_VERSION, why)
        elif handler is None:
            self._refuse(msg, Status.UNKNOWN_SERVICE, f"unknown service 0x{msg.service:02X}")
        else:
            if self._unlocked():
                self._session_until = c.polls + round(SESSION_S * self.rate_hz)
            try:
                body = handler(msg)
            except ServiceError as exc:
                self._refuse(msg, exc.status, str(exc))
            else:
                if body is not None:
                    self._respond(msg, Status.OK, body)
        return msg.service

    def _unlocked(self) -> bool:
        return self.counters.polls < self._session_until

    def _need_session(self, what: str) -> None:
        if not self._unlocked():
            raise ServiceError(Status.LOCKED, f"{what} needs an unlocked session (seed and key)")

    def _identify(self, msg: Message) -> dict:
        b = self.boot
        return {
            "firmware": FIRMWARE,
            "build": self._build,
            "protocol": VERSION,
            "param_crc": self.table.crc(),
            "params": len(TABLE),
            "rate_hz": self.rate_hz,
            "storage": b.state,
            "slot": b.slot,
            "sequence": b.sequence,
        }

    def summary(self) -> dict[str, int | float]:
        """Frame and request counters, and the time the port took per tick (worst and mean)."""
        return dict(zip(COUNTER_NAMES, self._counter_values(), strict=True))

    def _counter_values(self) -> list[int | float]:
        c = self.counters
        s = self.decoder.stats
        polls = max(c.polls, 1)
        return [
            c.rx_bytes, c.tx_bytes, s.frames, s.malformed, s.crc_errors, s.oversized,
            c.bad_messages, c.unexpected, c.requests, c.repeats, c.queue_overflow, c.tx_dropped,
            c.stream_samples, c.polls, round(c.worst_s * 1e6, 1), round(c.worst_cpu_s * 1e6, 1),
            round(c.total_s / polls * 1e6, 1), round(c.total_cpu_s / polls * 1e6, 1),
        ]  # fmt: skip

    def _counters(self, msg: Message) -> list[int | float]:
        return self._counter_values()  # values only, in COUNTER_NAMES order: names would not fit

    def _stream(self, msg: Message) -> dict:
        rate = _arg(msg.body, "rate_hz", (int, float))
        if rate != 0 and not MIN_STREAM_HZ <= rate <= self.rate_hz:
            raise ServiceError(
                Status.OUT_OF_RANGE,
                f"rate_hz={rate}: must be 0 (stop) or in {MIN_STREAM_HZ}..{self.rate_hz}",
            )
        self._stream_every = max(1, round(self.rate_hz / rate)) if rate > 0 else 0
        actual = self.rate_hz / self._stream_every if self._stream_every else 0
        return {"rate_hz": actual, "every": self._stream_every, "fields": len(live.FIELDS)}

    def _param_info(self, msg: Message) -> dict:
        index = _arg(msg.body, "index", int)
        if not 0 <= index < len(TABLE):
            raise ServiceError(Status.UNKNOWN_PARAM, f"index={index}: 0..{len(TABLE) - 1}")
        spec = TABLE[index]
        return {
            "index": index,
            "name": spec.name,
            "unit": spec.unit,
            "frac": spec.frac_bits,
            "lo": spec.raw_lo,
            "hi": spec.raw_hi,
            "run_safe": spec.run_safe,
            "raw": self.table.raw(spec.name),
        }

    def _spec_name(self, msg: Message) -> str:
        name = _arg(msg.body, "name", str)
        if name not in {s.name for s in TABLE}:
            raise ServiceError(Status.UNKNOWN_PARAM, f"unknown parameter {name!r}")
        return name

    def _param_read(self, msg: Message) -> dict:
        name = self._spec_name(msg)
        return {"name": name, "raw": self.table.raw(name), "frac": self.table.spec(name).frac_bits}

    def _param_write(self, msg: Message) -> dict:
        name = self._spec_name(msg)
        raw = _arg(msg.body, "raw", int)
        self._need_session("writing a parameter")
        if not isinstance(self.ecu, Ecu):
            raise ServiceError(
                Status.INVALID, "this tick implementation takes parameters at power-up only"
            )
        try:
            params, firmware = self.table.check_write(name, raw, self.ecu.out.mode == M.RUN)
        except WriteRefused as exc:
            raise ServiceError(Status[exc.reason], str(exc)) from None
        self.table.commit(params, firmware)
        self.ecu.p = firmware  # applies from the next tick
        return {**self._param_read(msg), "param_crc": self.table.crc()}

    def _param_save(self, msg: Message) -> None:
        self._need_session("saving the parameters")
        if self.boot.flash is None:
            raise ServiceError(Status.STORAGE, "no flash image (start the ECU with --flash FILE)")
        if self._writer is not None or self.boot.saving is not None:
            raise ServiceError(Status.BUSY, "a save is in progress")
        try:
            self._writer = self.boot.flash.writer(
                self.table.stored_image(L.stored_dict(self.ecu.s))
            )
        except OSError as exc:
            raise ServiceError(Status.STORAGE, f"flash image unreadable: {exc}") from None
        self.boot.saving = self
        self._save_request = msg  # answered when the last flash operation is done

    def _flash_step(self) -> None:
        """One flash operation of the save under way; its answer once the last one is done."""
        assert self._writer is not None and self._save_request is not None
        try:
            done = self._writer.step()
        except OSError as exc:
            self._refuse(self._save_request, Status.STORAGE, f"flash write failed: {exc}")
            self._writer = self._save_request = self.boot.saving = None
            return
        if not done:
            return
        slot = self._writer.slot
        self.boot.state, self.boot.slot, self.boot.sequence = "loaded", slot.index, slot.sequence
        body = {"slot": slot.index, "sequence": slot.sequence, "param_crc": self.table.crc()}
        self._respond(self._save_request, Status.OK, body)
        self._writer = self._save_request = self.boot.saving = None

    def _logbook_read(self, msg: Message) -> list[int]:
        """The engine's logbook as the firmware holds it: values only, in the order of
        ecu.logbook.word_names (names would not fit a frame)."""
        return L.stored_words(self.ecu.s)

    def _fault_log_read(self, msg: Message) -> dict:
        start = _arg(msg.body, "start", int, 0)
        entries = list(self.fault_log.entries)
        if not 0 <= start <= len(entries):
            raise ServiceError(Status.OUT_OF_RANGE, f"start={start}: 0..{len(entries)}")
        return {
            "total": self.fault_log.total,
            "count": len(entries),
            "rate_hz": self.rate_hz,
            "entries": [e.wire() for e in entries[start : start + FAULT_PAGE]],
        }

    def _fault_log_clear(self, msg: Message) -> dict:
        self._need_session("clearing the fault log")
        return {"cleared": self.fault_log.clear()}

    def _unlock_seed(self, msg: Message) -> dict:
        self._seed = self._rng.getrandbits(32)
        return {"seed": self._seed}

    def _unlock_key(self, msg: Message) -> dict:
        key = _arg(msg.body, "key", int)
        seed, self._seed = self._seed, None
        if seed is None:
            raise ServiceError(Status.BAD_REQUEST, "ask for a seed first (UNLOCK_SEED)")
        if key != unlock_key(seed):
            raise ServiceError(Status.BAD_KEY, "key does not match the seed; ask for a new seed")
        self._session_until = self.counters.polls + round(SESSION_S * self.rate_hz)
        return {"unlocked": True, "timeout_s": SESSION_S}

    def _arm(self, msg: Message) -> dict:
        self._need_session("arming")
        try:
            self.bench_control.arm()
        except BenchRefused as exc:
            raise ServiceError(Status[exc.reason], str(exc)) from None
        return {"mode": self.ecu.out.mode, "source": self.bench_control.source_name}

    def _stop(self, msg: Message) -> dict:
        self.bench_control.stop()
        return {"mode": self.ecu.out.mode}

    def _throttle(self, msg: Message) -> dict:
        pct = _arg(msg.body, "pct", (int, float))
        self._need_session("the throttle")
        try:
            self.bench_control.throttle(pct)
        except BenchRefused as exc:
            raise ServiceError(Status[exc.reason], str(exc)) from None
        return {
            "demand_pct": self.bench.throttle_cpct / 100,
            "source": self.bench_control.source_name,
        }
