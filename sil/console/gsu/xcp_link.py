"""The ground-support page's XCP session with the ECU: parameters, the bench's commands, the
test functions and the logbook, by the A2L's names, through pyXCP on a bus of its own.

Every command goes to the ECU, which checks it as it checks any master's: the page sends
nothing the firmware would not take from another tool, and what the ECU refuses comes back as
:class:`Refused` with the XCP error and what that error means for the command. CAL/PAG stays
locked until :meth:`XcpLink.unlock` (the user's own act on the page): the ECU then refuses
every write, as the service port does before its unlock. One command at a time (pyXCP's master
is not shared between threads).

XCP on CAN has one request and one response identifier: an answer does not say which master
asked. So the link watches the request identifier (:class:`Watch`) and takes an answer as its
own only when no other master's command frame came near it; a read is then asked again, a write
is reported as not confirmed. It asks nothing while the ECU is silent (its status frames, as
the page's live values see them, stopped) nor before the ECU has run :data:`SETTLE_S` again,
so that what the ECU answers late (commands that waited while it was paused) is never taken for
the answer to a later command. Every request waits :data:`REQUEST_TIMEOUT_S` at most; what
cannot be asked now is :class:`Unavailable`, at once.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import struct
import threading
import time
from collections.abc import Callable

import can

from ecu.xcp.codes import Cmd, Err
from sil.record.a2l import A2l, Characteristic
from sil.record.xcp_master import connect, master

REQUEST_TIMEOUT_S = 1.0  # one request's answer, at most
STORE_TIMEOUT_S = 10.0
LOCK_WAIT_S = 15.0  # for the command before (a store waits for the flash)
SETTLE_S = 0.3  # the ECU heard running this long (and this long after a lost answer) first
GUARD_S = 0.1  # another master's command this recent may be answered during ours
QUIET_WAIT_S = 1.0  # for a pause of GUARD_S in another master's commands, at most
ATTEMPTS = 3  # a read asked again after another master's command came near it
HEARD_S = 2.0  # another master's command this recent: the page says it is on the bus
ANOTHER_MASTER = "another XCP master is on the bus"
SIZES = {"UBYTE": "<B", "SBYTE": "<b", "UWORD": "<H", "SWORD": "<h", "ULONG": "<I", "SLONG": "<i"}
TESTS = {"glow": 1, "starter": 2, "prime": 3}

# what an XCP error means for a command of each kind (a parameter's OUT_OF_RANGE: its limits)
MEANING = {
    "parameter": {
        Err.ACCESS_LOCKED: "the ECU is locked: unlock it first",
        Err.ACCESS_DENIED: "the ECU refuses to change it while the engine runs",
        Err.VERIFY: "the ECU's parameter checks refuse the set (a table that falls or crosses)",
        Err.WRITE_PROTECTED: "read only",
    },
    "bench": {
        Err.ACCESS_LOCKED: "the ECU is locked: unlock it first",
        Err.OUT_OF_RANGE: "outside what the ECU takes",
        Err.ACCESS_DENIED: "the ECU's state refuses it",
    },
    "store": {
        Err.ACCESS_DENIED: "the ECU has no flash to store to",
        Err.CMD_BUSY: "a store is already under way",
        Err.ACCESS_LOCKED: "the ECU is locked: unlock it first",
    },
}


class Refused(Exception):
    """The ECU refused a command (``code``: its XCP error) or could not be asked (``code``
    None)."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


class Unavailable(Refused):
    """The ECU could not be asked now: it is silent or only just back, another master's
    command came near ours, or the answer did not come (``timed_out``)."""

    def __init__(self, message: str, timed_out: bool = False) -> None:
        super().__init__(message)
        self.timed_out = timed_out


def error_name(code: int) -> str:
    try:
        return f"ERR_{Err(code).name}"
    except ValueError:
        return f"error 0x{code:02X}"


def physical(raw: int, conversion: dict | None) -> float | str:
    """A raw value through its A2L conversion (as :func:`sil.record.a2l.read_a2l` gives it:
    linear, a verbal table, or none)."""
    conv = conversion or {}
    if "a" in conv:
        return raw * conv["a"] + conv.get("b", 0.0)
    k = next((k for k in range(len(conv)) if conv.get(f"val_{k}") == raw), None)
    if k is not None:
        return conv[f"text_{k}"].decode()
    return raw


class Watch:
    """The XCP bus as pyXCP sees it, read by a thread of its own: the ECU's answers wait in a
    queue for pyXCP's listener (:meth:`recv`); the command frames of another master (a bus
    does not hear back what it sends) are counted, with the time of the last, and its CONNECTs
    and DISCONNECTs apart (the ECU's one session, locked again or ended)."""

    def __init__(self, bus: can.BusABC, ids: tuple[int, int]) -> None:
        self.bus = bus
        self.request_id, self.response_id = ids
        self.filters = None  # (what pyXCP saves and gives back; the watch keeps its own)
        self.foreign = 0
        self.foreign_s = -math.inf  # time.monotonic() of the last
        self.connects = 0
        self.disconnects = 0
        self.answers: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        bus.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids])
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._read, name="gsu-xcp-watch", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._closed.is_set():
            try:
                msg = self.bus.recv(0.1)
            except (can.CanError, OSError, ValueError):
                time.sleep(0.1)
                continue
            if msg is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            if msg.arbitration_id == self.request_id:
                self._foreign(bytes(msg.data))
            elif msg.arbitration_id == self.response_id:
                self.answers.put(msg)

    def _foreign(self, data: bytes) -> None:
        self.foreign_s = time.monotonic()  # (first: a command counted is one known recent)
        self.foreign += 1
        if data[:1] == bytes([Cmd.CONNECT]):
            self.connects += 1
        elif data[:1] == bytes([Cmd.DISCONNECT]):
            self.disconnects += 1

    # -- what pyXCP's CAN transport calls ------------------------------------------------------
    def recv(self, timeout: float | None = None) -> can.Message | None:
        try:
            return self.answers.get(timeout=timeout)
        except queue.Empty:
            return None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.bus.send(msg, timeout)

    def set_filters(self, filters: object = None) -> None:
        pass

    @property
    def state(self) -> object:
        return self.bus.state

    def __str__(self) -> str:
        return f"{self.bus} (watched)"

    # -- the link's ----------------------------------------------------------------------------
    def flush(self) -> None:
        """Forget the answers waiting (none of them is the answer to a command to come)."""
        with contextlib.suppress(queue.Empty):
            while True:
                self.answers.get_nowait()

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=1.0)


class XcpLink:
    """An XCP session with the ECU on ``bus``, by the names of ``a2l``; ``running_for`` says
    how long the ECU has been heard without a pause (0: silent now)."""

    def __init__(
        self,
        bus: can.BusABC,
        a2l: A2l,
        ids: tuple[int, int],
        running_for: Callable[[], float] = lambda: math.inf,
    ) -> None:
        self.watch = Watch(bus, ids)
        self.a2l = a2l
        self.ids = ids
        self.identification: str | None = None
        self.unlocked = False
        self.problem: str | None = None  # why the last command could not be asked, if it could not
        self._running_for = running_for
        self._lock = threading.Lock()
        self._stack: contextlib.ExitStack | None = None
        self._x = None  # pyXCP's Master while connected
        self._lost_s = -math.inf  # when an answer last did not come
        self._connects = self._disconnects = 0  # the other masters' seen, at our last look
        self._since = -math.inf  # (time.monotonic()) since when the ECU runs, at our last look

    # -- the session ---------------------------------------------------------------------------
    def close(self) -> None:
        with self._lock:
            if self._x is not None and self._running_for() > 0:
                with contextlib.suppress(Exception):
                    self._x.disconnect()
            self._drop()
        self.watch.close()

    def _drop(self) -> None:
        if self._stack is not None:
            with contextlib.suppress(Exception):
                self._stack.close()
        self._stack, self._x, self.unlocked = None, None, False

    def _session(self):  # noqa: ANN202 (pyXCP's Master)
        if self._x is None:
            stack = contextlib.ExitStack()
            logging.getLogger("pyxcp").disabled = True  # (its own console handler)
            x = stack.enter_context(master(self.watch, self.ids, None))
            x.transport.timeout = round(REQUEST_TIMEOUT_S * 1e9)  # ns
            try:
                connect(x, REQUEST_TIMEOUT_S)
                x.getCommModeInfo()
                self.identification = x.identifier(0)
            except Exception:
                stack.close()
                raise
            self._stack, self._x = stack, x
        return self._x

    def _ready(self, what: str) -> int:
        """Refuse at once what cannot be asked now; else wait for a pause in another master's
        commands, clear what waits from before and give the count of the other master's
        commands to compare after."""
        running, now = self._running_for(), time.monotonic()
        if running <= 0:
            raise Unavailable(f"{what}: the ECU is silent (no status frame on the bus)")
        if running < SETTLE_S or now - self._lost_s < SETTLE_S:
            raise Unavailable(f"{what}: the ECU is only just back; ask again in a moment")
        since = now - running
        if since > self._since + SETTLE_S:  # silent since our last look: maybe started again,
            self._drop()  # with no session
        self._since = since
        watch = self.watch
        if watch.connects != self._connects:  # the ECU's session was opened again: locked
            self._connects, self.unlocked = watch.connects, False
        if watch.disconnects != self._disconnects:  # ... or ended: ours too
            self._disconnects = watch.disconnects
            self._drop()
        deadline = now + QUIET_WAIT_S
        while True:
            foreign = watch.foreign
            quiet = time.monotonic() - watch.foreign_s
            if quiet >= GUARD_S:
                break
            if time.monotonic() > deadline:
                self.problem = ANOTHER_MASTER
                raise Unavailable(f"{what}: {ANOTHER_MASTER}")
            time.sleep(GUARD_S - quiet)
        self._flush()
        return foreign

    def _flush(self) -> None:
        self.watch.flush()
        if self._x is not None:
            with self._x.transport.resQueue_condition:
                self._x.transport.resQueue.clear()

    def _alone(self, foreign: int) -> bool:
        """No other master's command since ours began, and no answer left over."""
        left = self._x is not None and bool(self._x.transport.resQueue)
        return self.watch.foreign == foreign and not left

    def _lost(self) -> None:
        """An answer did not come (or was not this command's): connect again, once the ECU has
        answered what it may still have waiting."""
        self._lost_s = time.monotonic()
        self._drop()

    def _ask(self, what: str, ask: Callable, kind: str = "", meaning: dict | None = None,
             repeatable: bool = True) -> object:  # fmt: skip
        """``ask(master)``'s result, taken only when no other master's command came near it (a
        ``repeatable`` command is then asked again); its refusal as :class:`Refused`, the error
        explained by ``meaning`` (error -> text) or :data:`MEANING` of ``kind``."""
        from pyxcp.types import XcpResponseError, XcpTimeoutError

        if not self._lock.acquire(timeout=LOCK_WAIT_S):
            raise Unavailable(f"{what}: the page is still waiting for the ECU on a command before")
        try:
            for _ in range(ATTEMPTS if repeatable else 1):
                foreign, refusal = self._ready(what), None
                fresh = self._x is None  # (a session opened now: its CONNECT's answer too)
                try:
                    answer = ask(self._session())
                except XcpResponseError as exc:
                    answer, refusal = None, exc
                except Refused:
                    raise
                except (XcpTimeoutError, OSError, can.CanError):
                    self._lost()
                    self.problem = "the ECU does not answer"
                    said = f"the ECU did not answer within {REQUEST_TIMEOUT_S:g} s"
                    raise Unavailable(f"{what}: {said}", timed_out=True) from None
                except Exception as exc:  # an answer pyXCP cannot read as this command's
                    if not self._alone(foreign):  # (another master's)
                        if fresh:
                            self._drop()
                        continue
                    self._lost()
                    raise Unavailable(f"{what}: an answer that was not this command's "
                                      f"({type(exc).__name__}); ask again") from None  # fmt: skip
                if self._alone(foreign):
                    self.problem = None
                    if refusal is not None:
                        raise self._refusal(refusal, what, kind, meaning)
                    return answer
                if fresh:
                    self._drop()
            self.problem = ANOTHER_MASTER
            said = ANOTHER_MASTER if repeatable else f"not confirmed: {ANOTHER_MASTER}"
            raise Unavailable(f"{what}: {said}")
        finally:
            self._lock.release()

    def _refusal(self, exc: Exception, what: str, kind: str, meaning: dict | None) -> Refused:
        code = int(exc.get_error_code())  # type: ignore[attr-defined]
        said = {**MEANING.get(kind, {}), **(meaning or {})}.get(code, "refused")
        if code == Err.ACCESS_LOCKED:
            self.unlocked = False
        return Refused(f"{what}: {said} ({error_name(code)})", code)

    def status(self) -> dict:
        return {
            "connected": self._x is not None,
            "ecu": self.identification,
            "unlocked": self.unlocked,
            "ids": [f"0x{i:X}" for i in self.ids],
            "another_master": time.monotonic() - self.watch.foreign_s < HEARD_S,
            "problem": self.problem,
        }

    def unlock(self) -> None:
        """GET_SEED and UNLOCK of CAL/PAG, the resource every write needs."""
        self._ask("unlock", lambda x: x.cond_unlock("CALPAG"), "bench")
        self.unlocked = True

    # -- memory --------------------------------------------------------------------------------
    @staticmethod
    def _upload(x, address: int, size: int) -> bytes:  # noqa: ANN001
        out = b""
        while len(out) < size:
            n = min(4, size - len(out))
            out += bytes(x.shortUpload(n, address + len(out)))
        if len(out) != size:
            raise ValueError(f"{len(out)} bytes for {size}")
        return out

    def read_characteristic(self, c: Characteristic) -> float | list[float]:
        fmt = SIZES[c.datatype]
        width = struct.calcsize(fmt)
        raw = self._ask(f"read {c.name}", lambda x: self._upload(x, c.address, width * c.count),
                        "parameter")  # fmt: skip
        values = [c.to_value(v) for (v,) in struct.iter_unpack(fmt, raw)]  # type: ignore[arg-type]
        return values[0] if c.kind == "VALUE" else values

    def read_measurements(self, names: list[str]) -> dict[str, float | str]:
        """The measurements of ``names`` the A2L has, as physical values (or the name of an
        enumeration's value)."""
        m = self.a2l.measurements
        shown = [(n, m[n]) for n in names if n in m and m[n].datatype in SIZES]

        def ask(x) -> dict[str, float | str]:  # noqa: ANN001
            out: dict[str, float | str] = {}
            for name, m in shown:
                fmt = SIZES[m.datatype]
                (raw,) = struct.unpack(fmt, self._upload(x, m.address, struct.calcsize(fmt)))
                out[name] = physical(raw, m.conversion)
            return out

        return self._ask("read", ask, "parameter")  # type: ignore[return-value]

    def write_characteristic(self, c: Characteristic, values: list[float], kind: str) -> None:
        """Write ``values`` (physical) whole, reported done only when the ECU acknowledged it
        to this master; :class:`Refused` with the ECU's reason."""
        what = f"{c.name} = {', '.join(f'{v:g}' for v in values)}"
        try:
            raws = [c.to_raw(v) for v in values]
            data = b"".join(struct.pack(SIZES[c.datatype], r) for r in raws)
        except (struct.error, OverflowError, ValueError):
            raise Refused(f"{what}: not a value its type ({c.datatype}) holds") from None
        limits = f"outside its limits [{c.lower:g}, {c.upper:g}] {c.unit}".rstrip()
        meaning = {Err.OUT_OF_RANGE: limits} if kind == "parameter" else None
        # DOWNLOAD, with DOWNLOAD_NEXT beyond one frame
        self._ask(what, lambda x: x.push(c.address, 0, data), kind, meaning, repeatable=False)

    def store(self) -> None:
        """STORE_CAL_REQ and wait for the ECU to finish it."""

        def ask(x) -> None:  # noqa: ANN001
            x.setRequest(0x01, 0)
            deadline = time.monotonic() + STORE_TIMEOUT_S
            while x.getStatus().sessionStatus.storeCalRequest:
                if time.monotonic() > deadline:
                    raise Unavailable(f"store to flash: not done within {STORE_TIMEOUT_S:g} s")
                time.sleep(0.05)

        self._ask("store to flash", ask, "store", repeatable=False)

    # -- the bench -----------------------------------------------------------------------------
    def bench(self, name: str, value: float) -> None:
        """Write the bench's ``name`` (``bench_arm``, ``bench_stop``, ``bench_throttle``, ...)."""
        c = self.a2l.characteristics.get(name)
        if c is None:
            raise Refused(f"{name}: not in the A2L (an ECU without it)")
        self.write_characteristic(c, [value], "bench")

    def run_test(self, test: str, level: float, seconds: float) -> None:
        """Start a test function (``glow``, ``starter``, ``prime``) at ``level`` (V for the
        prime, % for the starter) for ``seconds``; the ECU times it out."""
        if test not in TESTS:
            raise Refused(f"{test}: no such test function (one of {', '.join(TESTS)})")
        level_raw = level * 1000 if test == "prime" else level * 100  # mV, 0.01 %
        try:
            self.bench_raw("bench_test_level", round(level_raw))
            self.bench_raw("bench_test_ms", round(seconds * 1000))
            self.bench_raw("bench_test", TESTS[test])
        except Refused as exc:  # named after the test rather than the bench word
            what = {"bench_test_level": "its level", "bench_test_ms": "its time"}
            word, _, why = str(exc).partition(": ")
            part = what.get(word.split(" = ")[0])
            said = f"{test} test{', ' + part if part else ''}: {why}"
            if isinstance(exc, Unavailable):
                raise Unavailable(said, exc.timed_out) from None
            raise Refused(said, exc.code) from None

    def bench_raw(self, name: str, raw: int) -> None:
        c = self.a2l.characteristics.get(name)
        if c is None:
            raise Refused(f"{name}: not in the A2L (an ECU without test functions)")
        self.write_characteristic(c, [c.to_value(raw)], "bench")
