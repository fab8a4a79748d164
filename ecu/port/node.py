"""The C CAN node (``ecu_node.c``) through ctypes, with the node interface of
:class:`ecu.node.EcuNode`, so a driver or the in-process bus runs either: ``start``,
``on_frame``, ``on_timeout``, ``on_period``, ``finished``, ``timeout_s``, ``frame_ids``,
``attach_xcp``, ``watch_bus`` and the counters. It runs a :class:`ecu.port.core.CEcu` (the C
core) and sends the same frames, byte for byte and in the same order, as
``EcuNode(ecu=CEcu(...))`` without a service port and with ``max_ticks=None``
(tests/port/test_node.py); with the C XCP slave (:class:`ecu.port.xcp.CXcpSlave`,
``attach_xcp``) as EcuNode with its Python slave.

The two records the wrapper shares with C (``ecu_can_frame_t``, ``ecu_node_config_t``) are read
from the library's field strings, as :mod:`ecu.port.core` reads the core's; the node itself is an
opaque buffer of ``ecu_node_size()`` bytes, read through accessor functions.

For compiled callers (a numba loop, a C extension): :func:`frame_fn_address` is the address of
``ecu_node_frame`` and :attr:`CEcuNode.address` that of the instance's ``ecu_node_t``.
"""

from __future__ import annotations

import ctypes
import re
from collections.abc import Callable
from functools import cache

from ecu.node import RECEIVED, SERVICE_IDLE_POLL_S, OtherEcuWatch
from ecu.port.core import CEcu, PortError, library
from ecu.port.xcp import CXcpSlave
from ecu.service.logbook_save import LogbookSaver
from protocol.codec import Codec
from protocol.lockstep import every_ticks
from protocol.node import SendFn

_FIELD = re.compile(r"(\w+) (\w+)(?:\[(\d+)\])?")
_C_TYPES = {
    "uint8_t": ctypes.c_uint8,
    "uint16_t": ctypes.c_uint16,
    "uint32_t": ctypes.c_uint32,
    "int8_t": ctypes.c_int8,
    "int16_t": ctypes.c_int16,
    "int32_t": ctypes.c_int32,
}
FRAME_FIELDS = ("id", "data")
CONFIG_FIELDS = ("lockstep", "every_status", "every_telemetry", "every_demand")


def _struct(lib: ctypes.CDLL, symbol: str, expected: tuple[str, ...], what: str) -> type:
    """A ctypes Structure from the library's "type name[n]" string, checked against the field
    names this module sets or reads."""
    start = ctypes.addressof(ctypes.c_char.in_dll(lib, symbol))
    text = ctypes.cast(start, ctypes.c_char_p).value.decode()
    fields: list[tuple[str, type]] = []
    for ctype, name, count in _FIELD.findall(text):
        if ctype not in _C_TYPES:
            raise PortError(f"ecu_node.h {what}.{name}: type {ctype} unknown to the wrapper")
        t = _C_TYPES[ctype]
        fields.append((name, t * int(count) if count else t))
    names = tuple(name for name, _ in fields)
    if names != expected:
        raise PortError(f"ecu_node.h {what} has fields {names}, the wrapper expects {expected}")
    return type(what, (ctypes.Structure,), {"_fields_": fields})


class _NodeLib:
    def __init__(self) -> None:
        lib = library().lib
        self.frame_t = _struct(lib, "ecu_can_frame_names", FRAME_FIELDS, "ecu_can_frame_t")
        self.config_t = _struct(lib, "ecu_node_config_names", CONFIG_FIELDS, "ecu_node_config_t")
        self.max_out = ctypes.c_int.in_dll(lib, "ecu_node_max_out").value
        vp = ctypes.c_void_p
        for name, args, res in (
            ("ecu_node_every", [ctypes.c_uint32, ctypes.c_uint32], ctypes.c_uint16),
            ("ecu_node_init", [vp, vp, vp], None),
            ("ecu_node_frame", [vp, ctypes.c_uint32, ctypes.c_char_p, vp], ctypes.c_int),
            ("ecu_node_timeout", [vp, vp], ctypes.c_int),
            ("ecu_node_period", [vp, vp], ctypes.c_int),
            ("ecu_node_size", [], ctypes.c_size_t),
            ("ecu_node_ticks", [vp], ctypes.c_uint32),
            ("ecu_node_tick", [vp], ctypes.c_uint16),
            ("ecu_node_late_sensor_frames", [vp], ctypes.c_uint32),
            ("ecu_node_demand_waits", [vp], ctypes.c_uint32),
            ("ecu_node_own_clock", [vp], ctypes.c_int),
            ("ecu_node_waiting", [vp], ctypes.c_int),
            ("ecu_node_inputs", [vp], ctypes.POINTER(library().inputs_t)),
            ("ecu_node_attach_xcp", [vp, vp], None),
            (
                "ecu_node_receive",
                [vp, ctypes.c_uint32, ctypes.c_char_p, ctypes.c_uint8, vp],
                ctypes.c_int,
            ),  # fmt: skip
            ("ecu_node_sensor_seen", [vp], ctypes.c_int),
        ):
            fn = getattr(lib, name)
            fn.argtypes = args
            fn.restype = res
        self.lib = lib


@cache
def node_library() -> _NodeLib:
    """The node's functions and records in the host library (built on first use)."""
    return _NodeLib()


def every(cycle_time_ms: int, rate_hz: int) -> int:
    """``ecu_node_every``: the C twin of :func:`protocol.lockstep.every_ticks`."""
    return node_library().lib.ecu_node_every(cycle_time_ms, rate_hz)


def frame_fn_address() -> int:
    """Address of ``int ecu_node_frame(ecu_node_t *, uint32_t, const uint8_t[8],
    ecu_can_frame_t[ECU_NODE_MAX_OUT])`` in the loaded library (valid while the process runs)."""
    return ctypes.cast(node_library().lib.ecu_node_frame, ctypes.c_void_p).value


class CEcuNode:
    """The C node on a C core: ``EcuNode``'s interface (see the module docstring). ``lockstep``
    selects the clocking as in EcuNode; ``max_ticks`` as EcuNode's (None: never finishes).

    Received frames of the node's IDs must have 8 data bytes, the contract's length (a
    ValueError otherwise); frames of other IDs are ignored, as EcuNode ignores them.
    """

    def __init__(
        self,
        ecu: CEcu,
        *,
        lockstep: bool = True,
        codec: Codec | None = None,
        max_ticks: int | None = None,
    ) -> None:
        if not isinstance(ecu, CEcu):
            raise TypeError(f"CEcuNode runs a C core (ecu.port.core.CEcu), not {type(ecu)}")
        nl = node_library()
        codec = codec or Codec()
        self.ecu = ecu  # kept alive: the node points at its ecu_t
        self.rate_hz = ecu.p.rate_hz
        self.lockstep = lockstep
        self.frame_ids = tuple(codec[m].frame_id for m in RECEIVED)
        self.every_status = every_ticks(codec["EcuStatus"].cycle_time_ms, self.rate_hz)
        self.every_telemetry = every_ticks(codec["EcuTelemetry"].cycle_time_ms, self.rate_hz)
        self.every_demand = every_ticks(codec["Demand"].cycle_time_ms, self.rate_hz)
        config = nl.config_t(
            lockstep=int(lockstep),
            every_status=self.every_status,
            every_telemetry=self.every_telemetry,
            every_demand=self.every_demand,
        )
        size = nl.lib.ecu_node_size()
        self._node = (ctypes.c_uint64 * ((size + 7) // 8))()  # 8-byte aligned, zeroed
        self.address: int = ctypes.addressof(self._node)
        self._ref = self._node  # (passed as the void * of every call)
        nl.lib.ecu_node_init(self._ref, ctypes.byref(ecu._ecu), ctypes.byref(config))
        self._out = (nl.frame_t * nl.max_out)()
        self._frame = nl.lib.ecu_node_frame
        self._timeout = nl.lib.ecu_node_timeout
        self._period = nl.lib.ecu_node_period
        self._lib = nl.lib
        self.finished = False
        # the inputs the next tick gets (EcuNode.i), a view into the node
        self.i = nl.lib.ecu_node_inputs(self._ref).contents
        self.max_ticks = max_ticks  # finished once this many ticks have run (None: never)
        self.service = None  # (EcuNode's service port: the C node has none)
        self.xcp: CXcpSlave | None = None  # the C XCP slave (attach_xcp), or None
        self._xcp_send_for: SendFn | None = None
        self._receive = nl.lib.ecu_node_receive
        self._codec = codec
        self.watch: OtherEcuWatch | None = None  # another ECU on the bus (watch_bus), or None
        # the logbook's save at rest (ecu.service.logbook_save), stepped once per tick run
        self.logbook_saver: LogbookSaver | None = None
        self._saver_ticks = 0

    def attach_xcp(self, slave: CXcpSlave) -> None:
        """Put the C XCP slave on the node (``ecu_node_attach_xcp``): its command frames are
        heard from now on, at any length; its packets go out during the node's calls, before
        the frames a call returns."""
        if slave.ecu is not self.ecu:
            raise ValueError("the XCP slave runs on another core than the node's")
        self._lib.ecu_node_attach_xcp(self._ref, slave.address)
        self.xcp = slave
        self.frame_ids = (*self.frame_ids, slave.cmd_id)

    def watch_bus(self, report: Callable[[str], None]) -> None:
        """EcuNode.watch_bus: another ECU's frames (those of this ECU's IDs) are heard from now
        on, before the C node sees any frame; a refusal ends the node."""

        def other_ecu(text: str) -> None:
            report(text)
            self.finished = self.finished or watch.refused is not None

        self.watch = watch = OtherEcuWatch(self._codec, self.rate_hz, self.lockstep, other_ecu)
        self.frame_ids = (*self.frame_ids, *watch.names)

    def _xcp_to(self, send: SendFn) -> None:
        """The slave's packets to ``send`` on its response ID (set once per driver)."""
        if self.xcp is not None and self._xcp_send_for is not send:
            res_id = self.xcp.res_id
            self.xcp._sink = lambda data: send(res_id, data)
            self._xcp_send_for = send

    def _send(self, count: int, send: SendFn) -> None:
        saver = self.logbook_saver
        if saver is not None and self.ticks != self._saver_ticks:
            self._saver_ticks = self.ticks
            saver.after_tick()
        out = self._out
        for k in range(count):
            frame = out[k]
            send(frame.id, bytes(frame.data))
        if count and self.max_ticks is not None and self.ticks >= self.max_ticks:
            self.finished = True

    # -- the node interface (protocol/node.py) -----------------------------------------------
    def start(self, send: SendFn) -> None:
        pass

    def on_frame(self, frame_id: int, data: bytes | bytearray, send: SendFn) -> None:
        watch = self.watch
        if watch is not None and (frame_id in watch.names or watch.refused is not None):
            if frame_id in watch.names:
                watch.heard(frame_id, self.ticks)
            return  # (a node that refused takes nothing more)
        if self.xcp is not None:
            self._xcp_to(send)
            if frame_id == self.xcp.cmd_id:
                data = bytes(data)[:8]
                self._receive(self._ref, frame_id, data, len(data), self._out)
                return
        if len(data) != 8:
            if frame_id in self.frame_ids:
                raise ValueError(f"frame {frame_id:#x} with {len(data)} data bytes: expected 8")
            return
        self._send(self._frame(self._ref, frame_id, bytes(data), self._out), send)

    def on_timeout(self, send: SendFn) -> None:
        if self.watch is not None and self.watch.refused is not None:
            return
        self._xcp_to(send)
        self._send(self._timeout(self._ref, self._out), send)

    def on_period(self, send: SendFn) -> None:
        if self.watch is not None and self.watch.period():
            return
        self._xcp_to(send)
        self._send(self._period(self._ref, self._out), send)

    # -- EcuNode's counters ------------------------------------------------------------------
    @property
    def timeout_s(self) -> float | None:
        """1 / rate_hz while the plant is silent (the node ticks on its own clock); with an XCP
        slave and no plant heard yet, EcuNode's poll period (a store goes on); else None."""
        if self._lib.ecu_node_own_clock(self._ref):
            return 1.0 / self.rate_hz
        if self.polling:
            return SERVICE_IDLE_POLL_S
        return None

    @property
    def polling(self) -> bool:
        """No plant heard yet, an XCP slave to serve: idle polls, not guard timeouts."""
        return (
            self.xcp is not None
            and not self._lib.ecu_node_own_clock(self._ref)
            and not self._lib.ecu_node_sensor_seen(self._ref)
        )

    @property
    def ticks(self) -> int:
        """Ticks run (modulo 2**32)."""
        return self._lib.ecu_node_ticks(self._ref)

    @property
    def tick(self) -> int:
        return self._lib.ecu_node_tick(self._ref)

    @property
    def late_sensor_frames(self) -> int:
        return self._lib.ecu_node_late_sensor_frames(self._ref)

    @property
    def demand_waits(self) -> int:
        return self._lib.ecu_node_demand_waits(self._ref)

    @property
    def waiting(self) -> bool:
        return bool(self._lib.ecu_node_waiting(self._ref))
