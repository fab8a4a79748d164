"""The A2L as the field's tools read it (pya2ldb): the measurements, the characteristics
(parameters and the bench's commands), the XCP identifiers, events and EPK. pya2ldb is imported
only when an A2L is read (it is the ``xcp`` extra).

    a2l = read_a2l(Path("turbojet_ecu.a2l"))
    a2l.characteristics["egt_limit_k"].to_raw(1250.0)
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sil.record import mdf
from sil.validation import InputError, input_file

XCP_INSTALL = "pip install 'turbojet-sil[xcp]' (pyxcp, pya2ldb, asammdf)"

# A2L data types: pyXCP's DAQ type and the raw values' numpy type
TYPES = {
    "UBYTE": ("U8", np.uint8), "SBYTE": ("I8", np.int8),
    "UWORD": ("U16", np.uint16), "SWORD": ("I16", np.int16),
    "ULONG": ("U32", np.uint32), "SLONG": ("I32", np.int32),
    "A_UINT64": ("U64", np.uint64), "A_INT64": ("I64", np.int64),
    "FLOAT32_IEEE": ("F32", np.float32), "FLOAT64_IEEE": ("F64", np.float64),
}  # fmt: skip


class A2lError(Exception):
    """An A2L that cannot be read, or a name it lacks; the message says why in one line.
    ``code``: 2 for what the user gave (an A2L, a name, a missing package), 1 for what
    happened."""

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


@dataclass(frozen=True)
class Characteristic:
    """A CHARACTERISTIC of the A2L (a VALUE, or a CURVE of ``count`` points), with a linear
    conversion: physical = ``factor`` × raw + ``offset``."""

    name: str
    address: int
    kind: str  # VALUE or CURVE
    count: int
    datatype: str
    factor: float
    offset: float
    unit: str
    lower: float
    upper: float
    comment: str

    def to_raw(self, value: float) -> int:
        return round((value - self.offset) / self.factor)

    def to_value(self, raw: int) -> float:
        return raw * self.factor + self.offset


@dataclass
class A2l:
    """What the project's tools take from an A2L."""

    measurements: dict[str, Measurement]
    ids: tuple[int, int] | None  # XCP_ON_CAN: master, slave
    events: dict[int, str] = field(default_factory=dict)  # number -> name
    epk: str | None = None
    name: str = ""
    characteristics: dict[str, Characteristic] = field(default_factory=dict)


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
    """The measurements, characteristics, XCP identifiers, events and EPK of an A2L
    (A2lError: not readable, or pya2ldb missing)."""
    try:
        input_file(path, f"--a2l {path}")
    except InputError as exc:
        raise A2lError(str(exc)) from None
    if not path.is_file():
        raise A2lError(f"--a2l {path}: no such file")
    said: list[str] = []
    try:
        a2l = _read_a2l(path, said)
    except A2lError:
        a2l = None
        if not _parser_error(said):
            raise
    error = _parser_error(said)
    if error:  # a syntax error: what the parser said, rather than what it then missed
        raise A2lError(f"--a2l {path}: pya2ldb's parser: {error}") from None
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
            raise A2lError(f"the A2L needs pya2ldb ({exc}); install: {XCP_INSTALL}") from None
        session = None
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
            characteristics = _characteristics(session, model, methods)
            if_data = session.parse_ifdata(module.if_data) if module.if_data else []
            master, slave = _find(if_data, "CAN_ID_MASTER"), _find(if_data, "CAN_ID_SLAVE")
            events = {}
            for event in _find(if_data, "EVENT") or []:
                if isinstance(event, list) and len(event) > 2:
                    events[int(event[2])] = str(event[0])
            mod_par = session.query(model.ModPar).first()
            epk = mod_par.epk.identifier if mod_par is not None and mod_par.epk else None
            name = module.name
        except A2lError:
            raise
        except Exception as exc:  # pya2ldb's parser: a file it cannot read
            raise A2lError(f"--a2l {path}: cannot read it: {mdf.one_line(exc)}") from None
        finally:
            # Closed here, in the thread that read it: left to the collector, its SQLite
            # connection could be closed from another thread (the page's), which SQLite refuses
            # with a traceback on the terminal.
            if session is not None:
                session.close()
    ids = (int(master), int(slave)) if master is not None and slave is not None else None
    return A2l(measurements, ids, events, epk, name, characteristics)


def _characteristics(session, model, methods: dict) -> dict[str, Characteristic]:  # noqa: ANN001 (pya2ldb's)
    """The VALUE and CURVE characteristics with a linear (or no) conversion."""
    layouts = {r.name: r for r in session.query(model.RecordLayout)}
    out: dict[str, Characteristic] = {}
    for c in session.query(model.Characteristic):
        if c.type not in ("VALUE", "CURVE"):
            continue
        method = methods.get(c.conversion)
        factor, offset, unit = 1.0, 0.0, ""
        if method is not None:
            if method.conversionType == "LINEAR":
                factor, offset = float(method.coeffs_linear.a), float(method.coeffs_linear.b)
            elif method.conversionType != "IDENTICAL":
                continue  # (a verbal or rational parameter: none in the project's A2L)
            unit = method.unit or ""
        if c.phys_unit is not None and c.phys_unit.unit:
            unit = c.phys_unit.unit
        layout = layouts.get(c.deposit)
        out[c.name] = Characteristic(
            name=c.name,
            address=c.address,
            kind=c.type,
            count=c.axis_descr[0].maxAxisPoints if c.type == "CURVE" else 1,
            datatype=layout.fnc_values.datatype if layout is not None else "SLONG",
            factor=factor,
            offset=offset,
            unit=unit,
            lower=float(c.lowerLimit),
            upper=float(c.upperLimit),
            comment=c.longIdentifier or "",
        )
    return out


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
    """A COMPU_METHOD as asammdf's conversion and its unit (A2lError for a kind MDF 4
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
    raise A2lError(
        f"measurement {name}: its COMPU_METHOD {method.name} ({kind}) is not one MF4 carries "
        "here (LINEAR, IDENTICAL, RAT_FUNC without squares, TAB_VERB, TAB_INTP, TAB_NOINTP)"
    )
