"""The ground-support page's XCP session with the ECU: parameters, the bench's commands, the
test functions and the logbook, by the A2L's names, through pyXCP on a bus of its own.

Every command goes to the ECU, which checks it as it checks any master's: the page sends
nothing the firmware would not take from another tool, and what the ECU refuses comes back as
:class:`Refused` with the XCP error and what that error means for the command. CAL/PAG stays
locked until :meth:`XcpLink.unlock` (the user's own act on the page): the ECU then refuses
every write, as the service port does before its unlock. One command at a time (pyXCP's master
is not shared between threads); a session the ECU no longer answers is opened again on the
next command.
"""

from __future__ import annotations

import contextlib
import logging
import struct
import threading
import time
from collections.abc import Iterator

import can

from ecu.xcp.codes import Err
from sil.record.a2l import A2l, Characteristic
from sil.record.xcp_master import connect, master

CONNECT_TIMEOUT_S = 3.0
STORE_TIMEOUT_S = 10.0
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
    """The ECU refused a command (``code``: its XCP error) or did not answer (``code`` None)."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


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


class XcpLink:
    """An XCP session with the ECU on ``bus``, by the names of ``a2l``."""

    def __init__(self, bus: can.BusABC, a2l: A2l, ids: tuple[int, int]) -> None:
        self.bus = bus
        self.a2l = a2l
        self.ids = ids
        self.identification: str | None = None
        self.unlocked = False
        self._lock = threading.Lock()
        self._stack: contextlib.ExitStack | None = None
        self._x = None  # pyXCP's Master while connected

    # -- the session ---------------------------------------------------------------------------
    def close(self) -> None:
        with self._lock:
            self._drop()

    def _drop(self) -> None:
        if self._stack is not None:
            with contextlib.suppress(Exception):
                self._x.disconnect()
            with contextlib.suppress(Exception):
                self._stack.close()
        self._stack, self._x, self.unlocked = None, None, False

    def _session(self):  # noqa: ANN202 (pyXCP's Master)
        if self._x is None:
            stack = contextlib.ExitStack()
            logging.getLogger("pyxcp").disabled = True  # (its own console handler)
            x = stack.enter_context(master(self.bus, self.ids, None))
            try:
                connect(x, CONNECT_TIMEOUT_S)
                x.getCommModeInfo()
                self.identification = x.identifier(0)
            except Exception:
                stack.close()
                raise
            self._stack, self._x = stack, x
        return self._x

    @contextlib.contextmanager
    def _command(self, kind: str, what: str, meaning: dict | None = None) -> Iterator[object]:
        """One command on the session; its refusal as :class:`Refused`, the error explained by
        ``meaning`` (error -> text) or :data:`MEANING` of ``kind``."""
        from pyxcp.types import XcpResponseError, XcpTimeoutError

        with self._lock:
            try:
                yield self._session()
            except XcpResponseError as exc:
                code = int(exc.get_error_code())
                said = {**MEANING.get(kind, {}), **(meaning or {})}.get(code, "refused")
                if code == Err.ACCESS_LOCKED:
                    self.unlocked = False
                raise Refused(f"{what}: {said} ({error_name(code)})", code) from None
            except (XcpTimeoutError, OSError, can.CanError) as exc:
                self._drop()
                raise Refused(f"{what}: the ECU did not answer ({type(exc).__name__})") from None

    def status(self) -> dict:
        return {
            "connected": self._x is not None,
            "ecu": self.identification,
            "unlocked": self.unlocked,
            "ids": [f"0x{i:X}" for i in self.ids],
        }

    def unlock(self) -> None:
        """GET_SEED and UNLOCK of CAL/PAG, the resource every write needs."""
        with self._command("bench", "unlock") as x:
            x.cond_unlock("CALPAG")
            self.unlocked = True

    # -- memory --------------------------------------------------------------------------------
    def _upload(self, x, address: int, size: int) -> bytes:  # noqa: ANN001
        out = b""
        while len(out) < size:
            n = min(4, size - len(out))
            out += bytes(x.shortUpload(n, address + len(out)))
        return out

    def read_characteristic(self, c: Characteristic) -> float | list[float]:
        fmt = SIZES[c.datatype]
        width = struct.calcsize(fmt)
        with self._command("parameter", f"read {c.name}") as x:
            raw = self._upload(x, c.address, width * c.count)
        values = [c.to_value(v) for (v,) in struct.iter_unpack(fmt, raw)]
        return values[0] if c.kind == "VALUE" else values

    def read_measurements(self, names: list[str]) -> dict[str, float | str]:
        """The measurements of ``names`` the A2L has, as physical values (or the name of an
        enumeration's value)."""
        out: dict[str, float | str] = {}
        with self._command("parameter", "read") as x:
            for name in names:
                m = self.a2l.measurements.get(name)
                if m is None or m.datatype not in SIZES:
                    continue
                fmt = SIZES[m.datatype]
                (raw,) = struct.unpack(fmt, self._upload(x, m.address, struct.calcsize(fmt)))
                out[name] = physical(raw, m.conversion)
        return out

    def write_characteristic(self, c: Characteristic, values: list[float], kind: str) -> None:
        """Write ``values`` (physical) whole; :class:`Refused` with the ECU's reason."""
        raws = [c.to_raw(v) for v in values]
        what = f"{c.name} = {', '.join(f'{v:g}' for v in values)}"
        try:
            data = b"".join(struct.pack(SIZES[c.datatype], r) for r in raws)
        except struct.error:
            raise Refused(f"{what}: not a value its type ({c.datatype}) holds") from None
        limits = f"outside its limits [{c.lower:g}, {c.upper:g}] {c.unit}".rstrip()
        meaning = {Err.OUT_OF_RANGE: limits} if kind == "parameter" else None
        with self._command(kind, what, meaning) as x:
            x.push(c.address, 0, data)  # DOWNLOAD, with DOWNLOAD_NEXT beyond one frame

    def store(self) -> None:
        """STORE_CAL_REQ and wait for the ECU to finish it."""
        with self._command("store", "store to flash") as x:
            x.setRequest(0x01, 0)
            deadline = time.monotonic() + STORE_TIMEOUT_S
            while x.getStatus().sessionStatus.storeCalRequest:
                if time.monotonic() > deadline:
                    raise Refused(f"store to flash: not done within {STORE_TIMEOUT_S:g} s")
                time.sleep(0.05)

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
            raise Refused(f"{test} test{', ' + part if part else ''}: {why}", exc.code) from None

    def bench_raw(self, name: str, raw: int) -> None:
        c = self.a2l.characteristics.get(name)
        if c is None:
            raise Refused(f"{name}: not in the A2L (an ECU without test functions)")
        self.write_characteristic(c, [c.to_value(raw)], "bench")
