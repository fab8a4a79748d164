"""DAQ from the ECU's XCP slave into an MF4 with the A2L's names, units and conversions
(`sil xcp record`).

pyXCP is the master, on any bus of :mod:`protocol.bus`: it connects (retrying until the slave
answers), unlocks DAQ with the seed and key of :mod:`ecu.xcp.seed_key`, runs one DAQ list of
the measurements named on an event (0: the control tick) for a time or until told to stop, and
keeps every sample. The A2L, read with pya2ldb as the field's tools read it, gives each
measurement's address, type and COMPU_METHOD, and the XCP identifiers (``XCP_ON_CAN``); the MF4
(:func:`sil.record.mdf.write_measurements`) holds one channel group for the list: a channel per
measurement, named as in the A2L, with its raw values, its conversion (LINEAR, RAT_FUNC,
TAB_VERB, TAB_INTP, TAB_NOINTP) and its unit, so that a tool shows physical values. The time
channel is the ECU's DAQ timestamps (its clock: simulated time in lockstep) from the first
sample, as pyXCP hands them over (counted from the first, their wrap-around undone); the
header's start is the wall-clock time that first sample arrived.

    report = record(bus, Path("turbojet_ecu.a2l"), ["speed_rpm", "egt"], 5.0, Path("daq.mf4"))
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import os
import re
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from sil.record import mdf

XCP_INSTALL = "pip install 'turbojet-sil[xcp]' (pyxcp, pya2ldb, asammdf)"
# A2L data types: pyXCP's DAQ type and the raw values' numpy type
TYPES = {
    "UBYTE": ("U8", np.uint8), "SBYTE": ("I8", np.int8),
    "UWORD": ("U16", np.uint16), "SWORD": ("I16", np.int16),
    "ULONG": ("U32", np.uint32), "SLONG": ("I32", np.int32),
    "A_UINT64": ("U64", np.uint64), "A_INT64": ("I64", np.int64),
    "FLOAT32_IEEE": ("F32", np.float32), "FLOAT64_IEEE": ("F64", np.float64),
}  # fmt: skip


class RecordError(Exception):
    """A recording refused or failed; the message says why in one line. ``code``: 2 for what
    the user gave (an A2L, a name, a missing package), 1 for what happened (no answer, no
    sample)."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Measurement:
    """A MEASUREMENT of the A2L, as the recording needs it."""

    name: str
    address: int
    extension: int
    datatype: str
    unit: str
    comment: str
    conversion: dict | None  # asammdf's conversion (None: the raw value is the physical one)
    mask: int | None = None  # BIT_MASK: the value is (raw & mask) >> its lowest set bit


@dataclass
class A2l:
    """What a recording takes from an A2L."""

    measurements: dict[str, Measurement]
    ids: tuple[int, int] | None  # XCP_ON_CAN: master, slave
    events: dict[int, str] = field(default_factory=dict)  # number -> name
    epk: str | None = None
    name: str = ""


@contextlib.contextmanager
def _quiet_pya2l(said: list[str]) -> Iterator[None]:
    """pya2ldb logs its progress with a console handler of its own, installs its exception
    printer on import, and its compiled parser prints what it finds wrong on the process's
    standard output: none of it for a command's output; what was printed is put in ``said``."""
    hook = sys.excepthook
    loggers = [logging.getLogger(n) for n in ("pya2l", "pya2l.A2LDB", "pya2l.api", "sqlalchemy")]
    before = [lg.disabled for lg in loggers]
    for lg in loggers:
        lg.disabled = True
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    captured = tempfile.TemporaryFile()
    os.dup2(captured.fileno(), 1)
    os.dup2(captured.fileno(), 2)
    try:
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        with contextlib.suppress(OSError, AttributeError):  # the C library's buffers too
            ctypes.CDLL(None).fflush(None)
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)
        captured.seek(0)
        said.append(captured.read().decode("utf-8", "replace"))
        captured.close()
        sys.excepthook = hook
        for lg, was in zip(loggers, before, strict=True):
            lg.disabled = was


def read_a2l(path: Path) -> A2l:
    """The measurements, XCP identifiers, events and EPK of an A2L (RecordError: not readable,
    or pya2ldb missing)."""
    if not path.is_file():
        raise RecordError(f"--a2l {path}: no such file")
    said: list[str] = []
    try:
        a2l = _read_a2l(path, said)
    except RecordError:
        a2l = None
        if not _parser_error(said):
            raise
    error = _parser_error(said)
    if error:  # a syntax error: what the parser said, rather than what it then missed
        raise RecordError(f"--a2l {path}: pya2ldb's parser: {error}") from None
    assert a2l is not None
    return a2l


def _parser_error(said: list[str]) -> str | None:
    """The first error pya2ldb's parser printed, without its time and tags."""
    errors = [ln for ln in "".join(said).splitlines() if "[error]" in ln.lower()]
    return re.sub(r"^(\[[^\]]*\]\s*)+", "", errors[0].strip()) if errors else None


def _read_a2l(path: Path, said: list[str]) -> A2l:
    with _quiet_pya2l(said):
        try:
            import pya2l
            from pya2l import model
        except ImportError as exc:
            raise RecordError(f"the A2L needs pya2ldb ({exc}); install: {XCP_INSTALL}") from None
        try:
            session = pya2l.import_a2l(
                str(path), in_memory=True, progress_bar=False, loglevel="ERROR"
            )
            module = session.query(model.Module).first()
            if module is None:
                raise ValueError("no MODULE in it")
            methods = {c.name: c for c in session.query(model.CompuMethod)}
            vtabs = {v.name: v for v in session.query(model.CompuVtab)}
            tabs = {t.name: t for t in session.query(model.CompuTab)}
            measurements = {}
            for m in session.query(model.Measurement):
                if m.array_size is not None or m.matrix_dim is not None:
                    continue  # arrays: not recorded here
                method = methods.get(m.conversion)
                conversion, unit = _conversion(m.name, method, vtabs, tabs)
                if m.phys_unit is not None and m.phys_unit.unit:
                    unit = m.phys_unit.unit
                measurements[m.name] = Measurement(
                    name=m.name,
                    address=m.ecu_address.address if m.ecu_address is not None else 0,
                    extension=(m.ecu_address_extension.extension if m.ecu_address_extension else 0),
                    datatype=m.datatype,
                    unit=unit or "",
                    comment=m.longIdentifier or "",
                    conversion=conversion,
                    mask=m.bit_mask.mask if m.bit_mask is not None else None,
                )
            if_data = session.parse_ifdata(module.if_data) if module.if_data else []
            master, slave = _find(if_data, "CAN_ID_MASTER"), _find(if_data, "CAN_ID_SLAVE")
            events = {}
            for event in _find(if_data, "EVENT") or []:
                if isinstance(event, list) and len(event) > 2:
                    events[int(event[2])] = str(event[0])
            mod_par = session.query(model.ModPar).first()
            epk = mod_par.epk.identifier if mod_par is not None and mod_par.epk else None
            name = module.name
        except RecordError:
            raise
        except Exception as exc:  # pya2ldb's parser: a file it cannot read
            raise RecordError(f"--a2l {path}: cannot read it: {mdf.one_line(exc)}") from None
    ids = (int(master), int(slave)) if master is not None and slave is not None else None
    return A2l(measurements, ids, events, epk, name)


def _find(tree: object, key: str) -> object:
    """The first value of ``key`` in pya2ldb's parsed IF_DATA (nested lists and dicts)."""
    if isinstance(tree, dict):
        if key in tree:
            return tree[key]
        tree = list(tree.values())
    if isinstance(tree, list):
        for item in tree:
            found = _find(item, key)
            if found is not None:
                return found
    return None


def _conversion(name: str, method, vtabs: dict, tabs: dict) -> tuple[dict | None, str]:  # noqa: ANN001
    """A COMPU_METHOD as asammdf's conversion and its unit (RecordError for a kind MDF 4
    cannot carry here)."""
    if method is None:  # NO_COMPU_METHOD
        return None, ""
    kind, unit = method.conversionType, method.unit or ""
    if kind == "IDENTICAL":
        return None, unit
    if kind == "LINEAR":
        a, b = method.coeffs_linear.a, method.coeffs_linear.b
        return (None if (a, b) == (1, 0) else {"a": float(a), "b": float(b)}), unit
    if kind == "RAT_FUNC":  # A2L: raw = (a p^2 + b p + c) / (d p^2 + e p + f); MDF: p from raw
        c = method.coeffs
        if c.a == 0 and c.d == 0:  # raw = (b p + c) / (e p + f)  ->  p = (c - f raw) / (e raw - b)
            return {"P1": 0.0, "P2": -float(c.f), "P3": float(c.c), "P4": 0.0, "P5": float(c.e),
                    "P6": -float(c.b)}, unit  # fmt: skip
    elif kind == "TAB_VERB" and method.compu_tab_ref is not None:
        table = vtabs.get(method.compu_tab_ref.conversionTable)
        if table is not None:
            out: dict = {}
            for k, pair in enumerate(table.pairs):
                out[f"val_{k}"] = float(pair.inVal)
                out[f"text_{k}"] = str(pair.outVal).encode("utf-8")
            default = getattr(table.default_value, "display_string", "") or ""
            out["default_addr"] = str(default).encode("utf-8")
            return out, unit
    elif kind in ("TAB_INTP", "TAB_NOINTP") and method.compu_tab_ref is not None:
        table = tabs.get(method.compu_tab_ref.conversionTable)
        if table is not None:
            out = {"interpolation": kind == "TAB_INTP"}
            for k, pair in enumerate(table.pairs):
                out[f"raw_{k}"], out[f"phys_{k}"] = float(pair.inVal), float(pair.outVal)
            return out, unit
    raise RecordError(
        f"measurement {name}: its COMPU_METHOD {method.name} ({kind}) is not one MF4 carries "
        "here (LINEAR, IDENTICAL, RAT_FUNC without squares, TAB_VERB, TAB_INTP, TAB_NOINTP)"
    )


def pick(a2l: A2l, names: list[str]) -> list[Measurement]:
    """The A2L's measurements by name, in order (RecordError naming those it has not)."""
    missing = [n for n in names if n not in a2l.measurements]
    if missing:
        known = ", ".join(sorted(a2l.measurements)[:12])
        raise RecordError(
            f"--measure: {', '.join(missing)}: no such MEASUREMENT in the A2L (it has "
            f"{len(a2l.measurements)}: {known}, ...)"
        )
    unsupported = [n for n in names if a2l.measurements[n].datatype not in TYPES]
    if unsupported:
        raise RecordError(f"--measure: {', '.join(unsupported)}: a data type DAQ cannot record")
    if len(set(names)) != len(names):
        raise RecordError("--measure: a measurement named twice")
    return [a2l.measurements[n] for n in names]


# -- the master ----------------------------------------------------------------------------


def _policy(measurements: list[Measurement], event: int, prescaler: int):  # noqa: ANN202
    """pyXCP's DAQ policy keeping every sample of one list in memory: ``rows`` of (arrival
    time in ns since the epoch, the slave's timestamp in ns, the values)."""
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy

    daq_list = DaqList(
        name="sil_xcp_record",
        event_num=event,
        stim=False,
        enable_timestamps=True,
        measurements=[(m.name, m.address, m.extension, TYPES[m.datatype][0]) for m in measurements],
        priority=0,
        prescaler=prescaler,
    )

    class Keep(DaqOnlinePolicy):
        def __init__(self) -> None:
            super().__init__([daq_list], logger=logging.getLogger("sil.record.xcp_record"))
            self.pid_off = False  # (pyXCP sets it only when it reads its own configuration)
            self.rows: list[tuple[int, int, list]] = []
            self.lock = threading.Lock()

        @property
        def names(self) -> list[str]:
            return [h[0] for h in daq_list.headers]

        def initialize(self) -> None:
            pass

        def finalize(self) -> None:
            pass

        def on_daq_list(self, daq: int, ts0: int, ts1: int, payload: list) -> None:
            with self.lock:
                self.rows.append((time.time_ns(), ts1, list(payload)))

    return Keep()


def _master(bus: can.BusABC, ids: tuple[int, int], policy):  # noqa: ANN001, ANN202
    """pyXCP's master, configured in code, on ``bus``: XCP on CAN with ``ids``, the seed and
    key of :mod:`ecu.xcp.seed_key`, refusals raised (not pyXCP's own handling, which may end
    the process)."""
    from pyxcp.config import General, PyXCP, Transport
    from pyxcp.master import Master
    from traitlets.config import Config

    from ecu.xcp.seed_key import key_for

    c = Config()
    c.Transport.layer = "CAN"
    c.Transport.Can.interface = "virtual"  # (the bus is handed over, this is not opened)
    c.Transport.Can.can_id_master = ids[0]
    c.Transport.Can.can_id_slave = ids[1]
    c.General.seed_n_key_function = lambda resource, seed: key_for(bytes(seed))
    c.General.disable_error_handling = True
    app = PyXCP(config=c)
    app.log_level = logging.ERROR
    app._setup_logger()
    app.general = General(config=app.config, parent=app)
    app.transport = Transport(parent=app)
    return Master("CAN", config=app, policy=policy, transport_layer_interface=bus)


def _connect(x, timeout_s: float) -> None:  # noqa: ANN001 (pyXCP's Master)
    """CONNECT until the slave answers (an ECU not yet up, a run still starting), every 0.2 s
    rather than after the whole command timeout, so that no more of a lockstep run goes by
    than needed."""
    from pyxcp.types import XcpTimeoutError

    transport = x.transport
    normal = transport.timeout
    transport.timeout = 200_000_000  # ns
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            try:
                x.connect()
                return
            except XcpTimeoutError:
                if time.monotonic() > deadline:
                    raise
    finally:
        transport.timeout = normal


@dataclass
class Recording:
    """Samples of one DAQ list: time from the first (s, the ECU's clock), raw values."""

    measurements: list[Measurement]
    t: np.ndarray
    raw: dict[str, np.ndarray]
    start_us: int  # when the first sample arrived, µs since the epoch
    identification: str | None
    notes: list[str]


def record(
    bus: can.BusABC,
    a2l: A2l,
    measurements: list[Measurement],
    seconds: float,
    *,
    event: int = 0,
    prescaler: int = 1,
    connect_timeout_s: float = 10.0,
    stop: threading.Event | None = None,
    ids: tuple[int, int] | None = None,
) -> Recording:
    """Record ``measurements`` on ``event`` for ``seconds`` (or until ``stop`` is set) with
    pyXCP as the master on ``bus``. RecordError: pyXCP missing (2), no answer, a refusal, no
    sample (1). The end of a session the ECU no longer answers (it stopped) costs nothing of
    what was recorded: it is noted."""
    try:
        from pyxcp.types import XcpResponseError, XcpTimeoutError
    except ImportError as exc:
        raise RecordError(f"recording needs pyXCP ({exc}); install: {XCP_INSTALL}") from None
    ids = ids or a2l.ids
    if ids is None:
        from protocol.dbc import xcp_frame_ids

        ids = xcp_frame_ids()
    policy = _policy(measurements, event, prescaler)
    notes: list[str] = []
    where = f"the XCP slave (0x{ids[0]:X}/0x{ids[1]:X})"

    def session(x) -> tuple[RecordError | None, str | None]:  # noqa: ANN001 (pyXCP's Master)
        """The session; what went wrong is returned, not raised: pyXCP's master logs (with its
        traceback) an exception that leaves it."""
        try:
            _connect(x, connect_timeout_s)
        except XcpTimeoutError:
            return RecordError(f"no answer from {where} within {connect_timeout_s:g} s", 1), None
        try:
            x.getCommModeInfo()
            identification = x.identifier(0)
            x.cond_unlock("DAQ")
            policy.setup()
            policy.start()
        except (XcpResponseError, XcpTimeoutError, RuntimeError) as exc:
            return RecordError(f"{where} refused the DAQ list: {mdf.one_line(exc)}", 1), None
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            time.sleep(min(0.05, max(0.0, deadline - time.monotonic())))
        try:
            policy.stop()
            x.disconnect()
        except (XcpResponseError, XcpTimeoutError, OSError, can.CanError) as exc:
            notes.append(f"the session did not end cleanly ({mdf.one_line(exc)}): the ECU "
                         "stopped answering; what it sent before is kept")  # fmt: skip
        return None, identification

    pyxcp_log = logging.getLogger("pyxcp")
    disabled, pyxcp_log.disabled = pyxcp_log.disabled, True  # (its own console handler)
    try:
        with _master(bus, ids, policy) as x:
            failure, identification = session(x)
    finally:
        pyxcp_log.disabled = disabled
    if failure is not None:
        raise failure
    with policy.lock:
        rows = list(policy.rows)
    if not rows:
        raise RecordError(f"no DAQ sample from {where} on event {event}", 1)
    stamps = np.array([r[1] for r in rows], np.float64)  # ns, from the first, unwrapped
    t = (stamps - stamps[0]) / 1e9
    names = policy.names
    raw: dict[str, np.ndarray] = {}
    for m in measurements:
        column = np.array([r[2][names.index(m.name)] for r in rows])
        values = column.astype(TYPES[m.datatype][1])
        if m.mask is not None:
            shift = (m.mask & -m.mask).bit_length() - 1
            values = (values & values.dtype.type(m.mask)) >> values.dtype.type(shift)
        raw[m.name] = values
    if identification and a2l.epk and identification.strip() != a2l.epk.strip():
        notes.append(f"the ECU says '{identification}', the A2L's EPK is '{a2l.epk}': "
                     "an A2L of another build")  # fmt: skip
    return Recording(
        measurements=measurements,
        t=t,
        raw=raw,
        start_us=rows[0][0] // 1000,
        identification=identification,
        notes=notes,
    )


def write(path: Path, recording: Recording, a2l: A2l, a2l_path: Path, event: int) -> None:
    """The recording as an MF4 (atomically: WriteError names the file)."""
    event_name = a2l.events.get(event, f"event {event}")
    channels = [
        mdf.Channel(
            name=m.name, raw=recording.raw[m.name], conversion=m.conversion, unit=m.unit,
            comment=m.comment,
        )
        for m in recording.measurements
    ]  # fmt: skip
    comment = (
        f"XCP DAQ of {a2l.name or 'the ECU'} (A2L {a2l_path.name}; ECU "
        f"'{recording.identification or '?'}') on event {event} ({event_name}), recorded by "
        "turbojet-sil with pyXCP; time: the ECU's DAQ timestamps from the first sample, which "
        "arrived at the start" + "".join(f"; note: {n}" for n in recording.notes)
    )
    mdf.write_measurements(
        path,
        recording.start_us,
        recording.t,
        channels,
        group=event_name,
        source=a2l.name or "ECU",
        source_path="XCP on CAN",
        comment=comment,
    )


def summary(recording: Recording, path: Path, event: int) -> dict:
    n = len(recording.t)
    span = float(recording.t[-1]) if n else 0.0
    return {
        "out": str(path),
        "samples": n,
        "measurements": [m.name for m in recording.measurements],
        "event": event,
        "seconds": span,
        "rate_hz": (n - 1) / span if n > 1 and span > 0 else math.nan,
        "start": mdf.format_start(recording.start_us),
        "ecu": recording.identification,
        "notes": recording.notes,
    }
