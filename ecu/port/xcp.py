"""The C XCP slave (``ecu_xcp.c``) through ctypes, with the sans-IO interface of
:class:`ecu.xcp.slave.XcpSlave`: ``receive(data)``, ``serve(send)``, ``inputs(i)``,
``sample(send)``, the counters and ``summary()``. It runs on a :class:`ecu.port.core.CEcu` and
writes that core's parameters.

Its configuration (``ecu_xcp_config_t``) holds the run record (:mod:`ecu.port.xcp_run`), the
callbacks (packets out, the clock in real time, the store to a flash image, each a ctypes
callback into Python) and the seeds' generator. :class:`XorShiftSeeds` is that generator in
Python, for a Python slave that is to give the same seeds (the differential tests).

:func:`config_struct` is the configuration record for other callers of the C node
(:mod:`ecu.port.node` attaches the slave to the C node with it).
"""

from __future__ import annotations

import ctypes
import re
from collections.abc import Callable
from functools import cache
from pathlib import Path

import msgpack

from ecu import logbook as L
from ecu.port.core import CEcu, PortError, library
from ecu.port.xcp_run import run_record
from ecu.service.logbook_save import LogbookSaver
from ecu.service.param_table import TABLE, ParamTable
from ecu.service.storage import FlashImage, SlotWriter
from ecu.xcp import codes as C
from ecu.xcp.slave import DEFAULT_IDS, Limits

SEND_FN = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_uint32, ctypes.POINTER(ctypes.c_uint8), ctypes.c_uint8
)
CLOCK_FN = ctypes.CFUNCTYPE(ctypes.c_uint32, ctypes.c_void_p)
STORE_FN = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int)


class XcpConfig(ctypes.Structure):
    """ecu_xcp_config_t (ecu_xcp.h)."""

    _fields_ = [
        ("cmd_id", ctypes.c_uint32),
        ("res_id", ctypes.c_uint32),
        ("seed", ctypes.c_uint32),
        ("run", ctypes.POINTER(ctypes.c_int32)),
        ("params", ctypes.c_void_p),
        ("send", SEND_FN),
        ("clock_us", CLOCK_FN),
        ("store", STORE_FN),
        ("ctx", ctypes.c_void_p),
    ]


_C_TYPES = {"uint16_t": ctypes.c_uint16, "uint32_t": ctypes.c_uint32}
_FIELD = re.compile(r"(\w+) (\w+)")


class _XcpLib:
    def __init__(self) -> None:
        lib = library().lib
        start = ctypes.addressof(ctypes.c_char.in_dll(lib, "ecu_xcp_counter_names"))
        text = ctypes.cast(start, ctypes.c_char_p).value.decode()
        fields = [(name, _C_TYPES[t]) for t, name in _FIELD.findall(text)]
        self.kinds = 14
        fields.append(("errors", ctypes.c_uint16 * self.kinds))
        self.counters_t = type("ecu_xcp_counters_t", (ctypes.Structure,), {"_fields_": fields})
        vp = ctypes.c_void_p
        for name, args, res in (
            ("ecu_xcp_init", [vp, vp, vp], ctypes.c_int),
            ("ecu_xcp_receive", [vp, ctypes.c_char_p, ctypes.c_uint8], None),
            ("ecu_xcp_serve", [vp], None),
            ("ecu_xcp_inputs", [vp, vp, vp], ctypes.c_void_p),
            ("ecu_xcp_sample", [vp], None),
            ("ecu_xcp_size", [], ctypes.c_size_t),
            ("ecu_xcp_counters", [vp], ctypes.POINTER(self.counters_t)),
            ("ecu_xcp_error_code", [ctypes.c_int], ctypes.c_uint8),
            ("ecu_xcp_raw", [vp, ctypes.c_int], ctypes.c_int32),
            ("ecu_xcp_connected", [vp], ctypes.c_int),
            ("ecu_xcp_source", [vp], ctypes.c_int),
        ):
            fn = getattr(lib, name)
            fn.argtypes = args
            fn.restype = res
        values = (ctypes.c_int * 5).in_dll(lib, "ecu_xcp_limits")
        self.limits = Limits(*values)
        self.error_names = {}
        for k in range(self.kinds):
            code = lib.ecu_xcp_error_code(k)
            self.error_names[k] = C.Err(code).name
        self.lib = lib


@cache
def xcp_library() -> _XcpLib:
    return _XcpLib()


def c_limits() -> Limits:
    """What the C slave holds (a Python slave given these answers as it does)."""
    return xcp_library().limits


HEADER = Path(__file__).with_name("ecu_xcp.h")
_LIMIT_NAMES = ("QUEUE", "MAX_BS", "MAX_DAQ", "MAX_ODTS", "MAX_ENTRIES")


def header_limits() -> Limits:
    """What the C slave holds, as its header defines it (no compiler needed: ``sil a2l``)."""
    text = HEADER.read_text()
    values = []
    for name in _LIMIT_NAMES:
        found = re.search(rf"^#define ECU_XCP_{name} (\d+)\b", text, re.MULTILINE)
        if found is None:
            raise PortError(f"{HEADER}: no #define ECU_XCP_{name}")
        values.append(int(found.group(1)))
    return Limits(*values)


class XorShiftSeeds:
    """The C slave's seeds (xorshift32 from ``seed``) as a ``random.Random`` stand-in: give it
    to a Python slave (``slave._rng``) for the same GET_SEED answers."""

    def __init__(self, seed: int) -> None:
        self.state = seed or 1

    def getrandbits(self, bits: int) -> int:
        v = self.state
        v ^= (v << 13) & 0xFFFF_FFFF
        v ^= v >> 17
        v ^= (v << 5) & 0xFFFF_FFFF
        self.state = v
        return v


class FlashStore:
    """A store of the C slave's parameter set into a flash image (``--flash``), one flash
    operation a tick, as the Python slave's SET_REQUEST STORE_CAL_REQ."""

    def __init__(
        self,
        flash: FlashImage,
        raws: Callable[[], list[int]],
        logbook: Callable[[], dict[str, int]] = dict,
    ) -> None:
        self.flash = flash
        self.raws = raws
        self.logbook = logbook
        self.writer: SlotWriter | None = None
        self.saver: LogbookSaver | None = None  # the node's saves at rest, on this image

    def image(self) -> bytes:
        """The stored set: the slave's parameter set and the engine's logbook."""
        raws = {spec.name: raw for spec, raw in zip(TABLE, self.raws(), strict=True)}
        return msgpack.packb({**raws, L.STORE_KEY: self.logbook()})

    def __call__(self, begin: int) -> int:
        try:
            if begin:
                if self.saver is not None:
                    self.saver.writer = None  # this store takes the logbook as well
                self.writer = self.flash.writer(self.image())
                return 0
            assert self.writer is not None
            if self.writer.step():
                self.writer = None
                return 1
            return 0
        except (OSError, ValueError):
            self.writer = None
            return -1


class CXcpSlave:
    """The C slave on ``ecu``'s core and parameters (``table``: the set they were compiled
    from), sans-IO as XcpSlave. ``clock_us``: the clock of DAQ timestamps in real time (None:
    the ECU's ticks, simulated time); ``flash``: the image a store goes to (None: refused)."""

    def __init__(
        self,
        ecu: CEcu,
        table: ParamTable,
        *,
        ids: tuple[int, int] = DEFAULT_IDS,
        seed: int = 1,
        clock_us: Callable[[], int] | None = None,
        flash: FlashImage | None = None,
    ) -> None:
        if not isinstance(ecu, CEcu):
            raise TypeError(f"the C XCP slave runs on a C core (ecu.port.core.CEcu), not {ecu}")
        xl = xcp_library()
        self.ecu = ecu
        self.cmd_id, self.res_id = ids
        self.limits = xl.limits
        self._run = (ctypes.c_int32 * len(words := run_record(table)))(*words)
        self._sink: Callable[[bytes], None] = lambda data: None
        self._send_cb = SEND_FN(self._on_send)
        self._clock = clock_us
        self._clock_cb = CLOCK_FN(lambda ctx: clock_us() & 0xFFFF_FFFF) if clock_us else CLOCK_FN()
        logbook = lambda: L.stored_dict(ecu.s)  # noqa: E731
        self.store = FlashStore(flash, self.raws, logbook) if flash is not None else None
        self._store_cb = STORE_FN(lambda ctx, begin: self.store(begin)) if flash else STORE_FN()
        self.config = XcpConfig(
            cmd_id=self.cmd_id, res_id=self.res_id, seed=seed or 1,
            run=ctypes.cast(self._run, ctypes.POINTER(ctypes.c_int32)),
            params=ctypes.addressof(ecu._params), send=self._send_cb, clock_us=self._clock_cb,
            store=self._store_cb, ctx=None,
        )  # fmt: skip
        size = xl.lib.ecu_xcp_size()
        self._x = (ctypes.c_uint64 * ((size + 7) // 8))()
        self.address = ctypes.addressof(self._x)
        if xl.lib.ecu_xcp_init(self._x, ctypes.byref(ecu._ecu), ctypes.byref(self.config)) != 0:
            raise PortError("ecu_xcp_init refused the run record")
        self._lib = xl.lib
        self._bench = library().inputs_t()
        self._in = library().inputs_t()
        self._counters = xl.lib.ecu_xcp_counters(self._x).contents

    def _on_send(self, ctx, frame_id, data, length) -> None:  # noqa: ANN001
        self._sink(ctypes.string_at(data, length))

    # -- the sans-IO interface (ecu.xcp.slave.XcpSlave) ---------------------------------------
    def receive(self, data: bytes | bytearray) -> None:
        data = bytes(data)[:8]
        self._lib.ecu_xcp_receive(self._x, data, len(data))

    def serve(self, send: Callable[[bytes], None]) -> None:
        self._sink = send
        self._lib.ecu_xcp_serve(self._x)

    def sample(self, send: Callable[[bytes], None]) -> None:
        self._sink = send
        self._lib.ecu_xcp_sample(self._x)

    def inputs_c(self, inputs) -> int:  # noqa: ANN001 (an ecu_inputs_t)
        """ecu_xcp_inputs on a C inputs record: the address of the one the tick takes."""
        return self._lib.ecu_xcp_inputs(self._x, ctypes.byref(inputs), ctypes.byref(self._bench))

    # -- what it holds ------------------------------------------------------------------------
    def raws(self) -> list[int]:
        """Every parameter's raw value, in table order."""
        return [self._lib.ecu_xcp_raw(self._x, k) for k in range(len(TABLE))]

    @property
    def connected(self) -> bool:
        return bool(self._lib.ecu_xcp_connected(self._x))

    @property
    def source(self) -> int:
        return self._lib.ecu_xcp_source(self._x)

    def errors(self) -> dict[str, int]:
        names = xcp_library().error_names
        return {names[k]: n for k, n in enumerate(self._counters.errors) if n}

    def summary(self) -> dict:
        """The Python slave's summary keys from the C counters (no time per tick: the image's
        profile has its instructions)."""
        c = self._counters
        return {
            "impl": "c",
            "frames": c.frames,
            "served": c.served,
            "responses": c.responses,
            "errors": self.errors(),
            "ignored_not_connected": c.ignored,
            "empty_frames": c.empty,
            "queue_overflow": c.queue_overflow,
            "blocks_aborted": c.blocks_aborted,
            "events": c.events,
            "stores": c.stores,
            "store_failures": c.store_failures,
            "daq_samples": c.samples,
            "dtos": c.dtos,
            "ticks": c.ticks,
        }
