"""MDF4 (ASAM MDF 4.10, ``.mf4``) for the field's tools: CAN bus logs in the ASAM bus-logging
layout, and measurements (XCP DAQ) with their names, units and conversions.

A bus log holds a channel group per bus channel and kind of frame: ``CAN_DataFrame``, and
``CAN_ErrorFrame`` and ``CAN_RemoteFrame`` when the log has such frames. Each group is flagged
as bus events with a CAN bus source (named after the log's channel, ``vcan0``) and holds its
time channel and the structure channel named after the kind, with the members ``.BusChannel``,
``.ID``, ``.IDE``, ``.DLC``, ``.DataLength``, ``.DataBytes``, ``.Dir``, ``.EDL``, ``.BRS``,
``.ESI`` (a remote frame has no data): the layout python-can's and asammdf's own writers use,
which asammdf decodes with a DBC (``MDF.extract_bus_logging``) and its GUI, CANape and other
MDF4 tools open as a bus log.

Times: the header holds the absolute start, UTC, to the microsecond; the time channel counts
seconds from it, so that a tool's time axis starts at 0 and its clock shows the wall-clock
time. A log whose times are epoch times (a bench's ``candump -L``, BLF) starts at its first
frame; a log whose times count from its own start (a run's ``can.log``: simulated time) keeps
them as they are, and the start comes from elsewhere (the run's wall-clock start,
:func:`log_start`). The header's comment records which of the two the source was
(``frame_times``), so that converting back gives the source's times: ``can.log`` ->
``can.mf4`` -> ``can.log`` is the same file byte for byte.

asammdf is imported only when an MF4 is read or written (it is the ``mdf`` extra).
"""

from __future__ import annotations

import contextlib
import gc
import gzip
import heapq
import io
import json
import logging
import re
import struct
import sys
import warnings
import xml.etree.ElementTree as ET
from array import array
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import BinaryIO

import can
import numpy as np
from can.util import len2dlc

from sil.record.canlog import LogReadError
from sil.record.results import atomic

MAGIC = (b"MDF     ", b"UnFinMF ")  # a finished MDF file; one a logger did not finish
VERSION = "4.10"
TICK0_FIELD = "tick0_utc"  # summary.json: the wall-clock time of a run's tick 0, ISO 8601
EPOCH_FROM_S = 1e8  # a first frame at or after this (1973-03-03) carries epoch times
MDF_INSTALL = "pip install 'turbojet-sil[mdf]' (asammdf)"
KINDS = ("CAN_DataFrame", "CAN_ErrorFrame", "CAN_RemoteFrame")
_DATA, _ERROR, _REMOTE = range(3)
_CHUNK = 65_536  # records read at a time


class MdfUnavailable(RuntimeError):
    """asammdf cannot be imported here."""


def asammdf():  # noqa: ANN201 (the module)
    """The asammdf module, or :class:`MdfUnavailable` saying how to install it."""
    try:
        import asammdf as module
    except ImportError as exc:
        raise MdfUnavailable(f"MF4 needs asammdf, which cannot be imported here ({exc}); "
                             f"install it with: {MDF_INSTALL}") from None  # fmt: skip
    return module


def require(what: str) -> None:
    """ValueError naming ``what`` (an option) when asammdf cannot be imported here."""
    try:
        asammdf()
    except MdfUnavailable as exc:
        raise ValueError(f"{what}: {exc}") from None


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """asammdf logs what it finds wrong (and a half-read file's ``__del__`` fails on its way
    out): here the caller says what is wrong, in one line."""
    log = logging.getLogger("asammdf")
    disabled, hook = log.disabled, sys.unraisablehook
    log.disabled = True
    sys.unraisablehook = lambda _unraisable: None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        log.disabled, sys.unraisablehook = disabled, hook


def _attempt(action: Callable[[], object], collect: bool = False) -> tuple[object, str | None]:
    """``action()``'s result, or None and what it raised in one line; the exception and what it
    held freed while asammdf is :func:`quiet` (``collect``: a half-built reader, in a cycle)."""
    failure = None
    with quiet():
        try:
            return action(), None
        except Exception as exc:  # asammdf raises what its parser meets: a corrupt file
            failure = one_line(exc)
        if collect:
            gc.collect()
    return None, failure


# -- the frames of a log, as columns -------------------------------------------------------


@dataclass
class FrameTable:
    """A log's frames as columns, in the log's order."""

    t: np.ndarray  # float64 s, as the log gives them
    kind: np.ndarray  # uint8: 0 data, 1 error, 2 remote
    bus: np.ndarray  # uint16: index into ``channels``
    ident: np.ndarray  # uint32
    ide: np.ndarray  # uint8: extended ID
    dlc: np.ndarray  # uint8: the DLC code (CAN FD: of the length)
    length: np.ndarray  # uint8: data bytes
    data: np.ndarray  # (frames, 8) uint8, (frames, 64) with CAN FD frames
    tx: np.ndarray  # uint8: 1 transmitted, 0 received
    edl: np.ndarray  # uint8: CAN FD
    brs: np.ndarray
    esi: np.ndarray
    channels: list = field(default_factory=list)  # each bus channel as the log names it

    def __len__(self) -> int:
        return len(self.t)

    @classmethod
    def of(cls, frames: Iterable[can.Message]) -> FrameTable:
        """Every frame of ``frames`` (python-can messages), in columns as they come (about 30
        bytes a frame)."""
        cols = {name: array(code) for name, code in _COLUMNS}
        t, kind, bus, ident, ide, dlc, length, tx, edl, brs, esi = cols.values()
        payload = bytearray()  # 8 bytes a frame; longer CAN FD payloads kept aside
        long: dict[int, bytes] = {}
        channels: dict[object, int] = {}
        for m in frames:
            bus.append(channels.setdefault(m.channel, len(channels)))
            kind.append(_ERROR if m.is_error_frame else _REMOTE if m.is_remote_frame else _DATA)
            body = bytes(m.data or b"")[:64]
            if len(body) > 8:
                long[len(t)] = body
            t.append(m.timestamp or 0.0)
            ident.append(m.arbitration_id)
            ide.append(m.is_extended_id)
            dlc.append(m.dlc if not m.is_fd else len2dlc(len(body)))
            length.append(len(body))
            tx.append(not m.is_rx)
            edl.append(m.is_fd)
            brs.append(m.bitrate_switch)
            esi.append(m.error_state_indicator)
            payload += body[:8].ljust(8, b"\0")
        n = len(t)
        data = np.zeros((n, 64 if long else 8), np.uint8)
        data[:, :8] = np.frombuffer(bytes(payload), np.uint8).reshape(n, 8)
        for i, extra in long.items():
            data[i, : len(extra)] = np.frombuffer(extra, np.uint8)
        arrays = {name: np.frombuffer(col, col.typecode).copy() if len(col) else
                  np.zeros(0, col.typecode) for name, col in cols.items()}  # fmt: skip
        return cls(**arrays, data=data, channels=list(channels))


# FrameTable's columns and their array codes
_COLUMNS = (("t", "d"), ("kind", "B"), ("bus", "H"), ("ident", "I"), ("ide", "B"), ("dlc", "B"),
            ("length", "B"), ("tx", "B"), ("edl", "B"), ("brs", "B"), ("esi", "B"))  # fmt: skip


@dataclass(frozen=True)
class TimeBase:
    """Where a log's time axis starts: ``start_us`` (µs since the epoch, UTC) and whether the
    log's own times count from it (``relative``: a run's simulated time) or are epoch times."""

    start_us: int
    relative: bool
    origin: str  # where the start came from, for the user

    @property
    def start_s(self) -> float:
        return self.start_us / 1e6

    def iso(self) -> str:
        return format_start(self.start_us)


def format_start(start_us: int) -> str:
    """``2026-12-06T21:56:03.123456Z``."""
    when = datetime.fromtimestamp(start_us // 1_000_000, UTC).replace(
        microsecond=start_us % 1_000_000
    )
    return when.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def parse_start(text: str) -> float:
    """``--start``: epoch seconds, or an ISO 8601 date and time (UTC unless it says its zone);
    ValueError saying what it takes."""
    try:
        return float(text)
    except ValueError:
        pass
    try:
        when = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(
            f"start time '{text}' is neither epoch seconds nor an ISO 8601 date and time "
            "(2026-12-06T21:56:03Z)"
        ) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return when.timestamp()


def time_base(
    first_s: float | None, start_s: float | None, fallback: Callable[[], tuple[float, str]]
) -> TimeBase:
    """The time base of a log whose first frame is at ``first_s``: epoch times start at
    ``start_s`` if given, else at their first frame; times from the log's own start (below
    :data:`EPOCH_FROM_S`) keep their values, the start being ``start_s`` or ``fallback()``
    (the start and where it came from)."""
    absolute = first_s is not None and first_s >= EPOCH_FROM_S
    if start_s is not None:
        start, origin = start_s, "--start"
    elif absolute:
        start, origin = first_s, "the log's first frame"
    else:
        start, origin = fallback()
    return TimeBase(round(start * 1e6), not absolute, origin)


def log_start(path: Path, header_start_s: float | None = None) -> tuple[float, str]:
    """The wall-clock start of a log whose times count from its own start: the one its header
    gives (ASC's date), else, in a run's folder, the run's tick 0 (``summary.json``: the time
    every log the run wrote starts at), else the run's start (``run.json`` is written as the run
    begins), else the file's modification time."""
    if header_start_s is not None:
        return header_start_s, "the log's header"
    with contextlib.suppress(OSError, ValueError):  # (no summary, or not one of ours)
        summary = json.loads((path.parent / "summary.json").read_text())
        tick0 = summary.get(TICK0_FIELD) if isinstance(summary, dict) else None
        if isinstance(tick0, str):  # (a run still under way, or of before, has none)
            return parse_start(tick0), "the run's tick 0 (summary.json)"
    record = path.parent / "run.json"
    if record.is_file():
        return record.stat().st_mtime_ns / 1e9, "the run's start (run.json)"
    return path.stat().st_mtime_ns / 1e9, "the file's modification time (give --start to set it)"


# -- writing -------------------------------------------------------------------------------


def _dtype(kind: int, width: int) -> np.dtype:
    name = KINDS[kind]
    fields = [("BusChannel", "<u1"), ("ID", "<u4"), ("IDE", "<u1"), ("DLC", "<u1"),
              ("DataLength", "<u1")]  # fmt: skip
    if kind != _REMOTE:
        fields.append(("DataBytes", f"({width},)u1"))
    fields.append(("Dir", "<u1"))
    if kind != _REMOTE:
        fields += [("EDL", "<u1"), ("BRS", "<u1"), ("ESI", "<u1")]
    return np.dtype([(f"{name}.{n}", t) for n, t in fields])


def _header_comment(text: str, relative: bool) -> str:
    root = ET.Element("HDcomment")
    ET.SubElement(root, "TX").text = text
    common = ET.SubElement(root, "common_properties")
    ET.SubElement(common, "e", name="frame_times").text = "relative" if relative else "absolute"
    return ET.tostring(root, encoding="unicode")


def _new_mdf(start_us: int):  # noqa: ANN202 (asammdf.MDF)
    mdf = asammdf().MDF(version=VERSION)
    mdf.header.start_time = datetime.fromtimestamp(start_us // 1_000_000, UTC)
    mdf.header.abs_time = start_us * 1000  # exact, to the microsecond
    return mdf


def _save(mdf, path: Path) -> None:  # noqa: ANN001 (asammdf.MDF)
    """Save atomically (:func:`sil.record.results.atomic`), compressed, whatever the name's
    suffix."""
    with atomic(path) as tmp, tmp.open("wb+") as f:
        mdf.save(f, overwrite=True, compression=2)


def write_bus_log(path: Path, table: FrameTable, base: TimeBase, note: str = "") -> None:
    """Write ``table`` as an MF4 bus log starting at ``base`` (atomically; WriteError names
    the file)."""
    from asammdf.blocks.v4_blocks import SourceInformation
    from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS

    module = asammdf()
    t = table.t if base.relative else table.t - base.start_s
    mdf = _new_mdf(base.start_us)
    what = "times from the log's own start" if base.relative else "epoch times"
    mdf.header.comment = _header_comment(
        f"CAN bus log{': ' + note if note else ''} (turbojet-sil; the source's {what}; start "
        f"from {base.origin})",
        base.relative,
    )
    for bus, channel in enumerate(table.channels or [None]):  # (an empty log: an empty group)
        for kind, name in enumerate(KINDS):
            rows = np.flatnonzero((table.bus == bus) & (table.kind == kind))
            if not len(rows) and (kind != _DATA or len(table)):
                continue
            width = 64 if table.edl[rows].any() and table.data.shape[1] == 64 else 8
            s = np.zeros(len(rows), _dtype(kind, width))
            s[f"{name}.BusChannel"] = bus + 1
            s[f"{name}.ID"] = table.ident[rows]
            s[f"{name}.IDE"] = table.ide[rows]
            s[f"{name}.DLC"] = table.dlc[rows]
            s[f"{name}.DataLength"] = table.length[rows] if kind != _REMOTE else 0
            s[f"{name}.Dir"] = table.tx[rows]
            if kind != _REMOTE:
                s[f"{name}.DataBytes"] = table.data[rows, :width]
                for flag in ("EDL", "BRS", "ESI"):
                    s[f"{name}.{flag}"] = getattr(table, flag.lower())[rows]
            label = "" if channel is None else str(channel)
            source = SourceInformation(source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)
            source.name = label or f"CAN{bus + 1}"
            source.path = label or f"CAN{bus + 1}"
            signal = module.Signal(samples=s, timestamps=t[rows], name=name, source=source)
            mdf.append(signal, acq_name=source.name, acq_source=source)
    with quiet():
        _save(mdf, path)
    mdf.close()


# -- reading -------------------------------------------------------------------------------


_BLOCK = struct.Struct("<4s4xQQ")  # id, length, links


def check_blocks(f: BinaryIO, size: int) -> tuple[int, str] | None:
    """Where an MDF 4 file's structure breaks (the byte and what is wrong), or None. Every block
    reachable from the header's links must be a whole block inside the file (a file cut short
    loses the blocks written last: asammdf writes the groups' and channels' blocks after the
    data; that is named at the file's end, with the block that links past it), and every
    channel must lie in its group's records, which the data must hold (asammdf's compiled
    reader trusts these: a corrupt offset would crash it rather than fail)."""
    blocks: dict[int, tuple[bytes, tuple[int, ...], int]] = {}  # byte -> (kind, links, length)
    todo = [(64, b"ID")]  # (a block's byte, the kind of block that links to it)
    while todo:
        at, parent = todo.pop()
        if at in blocks or at == 0:
            continue
        via = f"the {parent.decode('latin-1')} block's link to byte {at}"
        if at + _BLOCK.size > size:
            return size, f"truncated MF4: {via} lies past the file's end ({size} bytes)"
        f.seek(at)
        ident, length, count = _BLOCK.unpack(f.read(_BLOCK.size))
        if not ident.startswith(b"##"):
            return at, f"corrupt MF4: no block at byte {at} ({via}; found {ident!r})"
        kind = ident[2:]
        if at + length > size:
            return size, (
                f"truncated MF4: the {kind.decode('latin-1')} block at byte {at} ({length} "
                f"bytes) ends past the file's end ({size} bytes)"
            )
        if length < _BLOCK.size + 8 * count or len(blocks) > 10_000_000:
            return at, f"corrupt MF4: the {kind.decode('latin-1')} block at byte {at} is malformed"
        links = struct.unpack(f"<{count}Q", f.read(8 * count))
        blocks[at] = (kind, links, length)
        todo += [(link, kind) for link in links]
    return _check_groups(f, blocks)


def _check_groups(f: BinaryIO, blocks: dict) -> tuple[int, str] | None:
    """Each channel group's channels inside its records, and its records inside its data."""

    def data(at: int, fmt: str) -> tuple:
        kind, links, length = blocks[at]
        f.seek(at + _BLOCK.size + 8 * len(links))
        raw = f.read(struct.calcsize(fmt))
        if len(raw) < struct.calcsize(fmt):
            raise _Malformed(at, kind)
        return struct.unpack(fmt, raw)

    def chain(at: int, kind: bytes, nxt: int = 0) -> Iterator[int]:
        hops = 0
        while at and hops < 1_000_000:
            if blocks.get(at, (b"",))[0] != kind:
                raise _Malformed(at, kind)
            yield at
            at, hops = blocks[at][1][nxt], hops + 1

    def held(at: int) -> int:  # the bytes a data link holds (DT, DZ, DL, HL, or none)
        if not at:
            return 0
        kind, links, length = blocks[at]
        if kind in (b"DT", b"DV", b"RD"):
            return length - _BLOCK.size - 8 * len(links)
        if kind == b"DZ":
            return data(at, "<2sBxIQQ")[3]
        if kind == b"HL":
            return held(links[0])
        if kind == b"DL":
            return sum(held(link) for dl in chain(at, b"DL") for link in blocks[dl][1][1:])
        return 0

    try:
        header = next(at for at, block in blocks.items() if block[0] == b"HD")
        for dg in chain(blocks[header][1][0], b"DG"):
            record_id = data(dg, "<B")[0]
            groups = list(chain(blocks[dg][1][1], b"CG"))
            for cg in groups:
                _, cycles, _, _, size, invalid = data(cg, "<QQHH4xII")
                channels = list(blocks[cg][1][1:2])
                while channels:
                    for cn in chain(channels.pop(), b"CN"):
                        cn_type, _, dtype, bit, byte, bits, flags, ipos = data(cn, "<BBBBIIII")
                        if blocks[cn][1][1] and blocks[blocks[cn][1][1]][0] == b"CN":
                            channels.append(blocks[cn][1][1])  # a structure's members
                        width = 64 if cn_type == 1 else bit + bits  # VLSD: its offset
                        if cn_type in (3, 6):  # virtual: no bytes in the record
                            continue
                        if byte + (width + 7) // 8 > size or dtype > 30:
                            raise _Malformed(cn, b"CN")
                        if flags & 2 and ipos >= 8 * invalid:
                            raise _Malformed(cn, b"CN")
            if len(groups) == 1:  # (sorted: every record of the one group, back to back)
                _, cycles, _, _, size, invalid = data(groups[0], "<QQHH4xII")
                need = cycles * (record_id + size + invalid)
                have = held(blocks[dg][1][2])
                if need > have:
                    return dg, (
                        f"corrupt MF4: the data group at byte {dg} holds {have} bytes for "
                        f"{cycles} records of {record_id + size + invalid} bytes"
                    )
    except _Malformed as exc:
        kind = exc.kind.decode("latin-1")
        return exc.at, f"corrupt MF4: the {kind} block at byte {exc.at} is malformed"
    except (KeyError, IndexError, StopIteration):
        return 64, "corrupt MF4: its blocks do not link as MDF 4's do"
    return None


class _Malformed(Exception):
    def __init__(self, at: int, kind: bytes) -> None:
        super().__init__(at, kind)
        self.at, self.kind = at, kind


class BusLogReader:
    """The frames of an MF4 bus log (CAN data, error and remote frames of every bus channel),
    merged in time; their times as the source's (see the module's notes), epoch times for an
    MF4 from elsewhere. :attr:`frames` counts those handed out. A file that cannot be read
    raises :class:`~sil.record.canlog.LogReadError`, at once for a broken structure, else naming the
    frame after which its data could not be read."""

    def __init__(self, path: Path, gz: bool = False) -> None:
        self.path = path
        self.gz = gz
        self.frames = 0
        self.start_us = 0
        self.relative = False

    def _error(self, position: str, reason: str) -> LogReadError:
        return LogReadError(self.path, position, reason, self.frames)

    def _open(self):  # noqa: ANN202 (asammdf.MDF)
        module = asammdf()
        if self.gz:
            try:
                raw = gzip.decompress(self.path.read_bytes())
            except (EOFError, OSError) as exc:
                raise self._error("byte 0", f"truncated gzip data: {exc}") from None
            source: Path | io.BytesIO = io.BytesIO(raw)
            size = len(raw)
            broken = check_blocks(source, size)
            source.seek(0)
        else:
            source = self.path
            size = self.path.stat().st_size
            with self.path.open("rb") as f:
                broken = check_blocks(f, size)
        if broken is not None:
            at, reason = broken
            raise self._error(f"byte {at}", reason)
        mdf, failure = _attempt(lambda: module.MDF(source), collect=True)
        if failure is not None:
            raise self._error("byte 0", f"corrupt MF4: {failure}")
        if not mdf.version.startswith("4"):
            mdf.close()
            raise self._error("byte 0", f"MDF {mdf.version}: a CAN bus log is MDF 4")
        return mdf

    def __iter__(self) -> Iterator[can.Message]:
        from asammdf.blocks.v4_constants import BUS_TYPE_CAN, FLAG_CG_BUS_EVENT

        mdf = self._open()
        try:
            header = mdf.header
            self.relative = _frame_times(header.comment) == "relative"
            self.start_us = _start_us(header)
            offset = 0.0 if self.relative else self.start_us / 1e6
            streams, groups = [], 0
            for index, group in enumerate(mdf.groups):
                cg = group.channel_group
                source = cg.acq_source
                if not cg.flags & FLAG_CG_BUS_EVENT or source is None:
                    continue
                if source.bus_type != BUS_TYPE_CAN:
                    continue
                names = {ch.name for ch in group.channels}
                kind = next((k for k, name in enumerate(KINDS) if name in names), None)
                groups += kind is not None
                if kind is not None and cg.cycles_nr:
                    streams.append(self._group(mdf, index, kind, cg.cycles_nr, offset, source))
            if not groups:
                raise self._error(
                    "byte 0", "no CAN bus logging in it (no CAN_DataFrame channel group)"
                )
            for message in heapq.merge(*streams, key=lambda m: m.timestamp):
                self.frames += 1
                yield message
        finally:
            with quiet():
                mdf.close()

    def _group(
        self,
        mdf,
        index: int,
        kind: int,
        records: int,
        offset: float,
        source,  # noqa: ANN001
    ) -> Iterator[can.Message]:
        name = KINDS[kind]
        label = source.name or None  # the log's channel: vcan0, or a number (ASC, BLF, TRC)
        channel = int(label) if label is not None and label.isdigit() else label
        for first in range(0, records, _CHUNK):
            signal, failure = _attempt(
                lambda first=first: mdf.get(
                    name, index, record_offset=first, record_count=_CHUNK, raw=True
                )
            )
            if failure is not None:  # a data block that does not decompress or parse
                where = f"frame {self.frames + 1}"
                raise self._error(where, f"corrupt MF4 data ({name}): {failure}")
            yield from _messages(signal, kind, offset, channel)


def _messages(signal, kind: int, offset: float, label) -> Iterator[can.Message]:  # noqa: ANN001
    s = signal.samples
    fields = set(s.dtype.names or ())
    name = KINDS[kind]

    def column(member: str, default: int = 0) -> list:
        key = f"{name}.{member}"
        if key not in fields:
            return [default] * len(s)
        values = s[key]
        if values.dtype.kind == "S":  # Dir as text ("Tx", "Rx")
            return [int(v == b"Tx") for v in values]
        return values.tolist()

    ident, ide = column("ID"), column("IDE")
    length, dlc = column("DataLength"), column("DLC")
    tx, edl, brs, esi = column("Dir"), column("EDL"), column("BRS"), column("ESI")
    bus = column("BusChannel")
    data = s[f"{name}.DataBytes"] if f"{name}.DataBytes" in fields else None
    times = (signal.timestamps + offset).tolist()
    for i, t in enumerate(times):
        payload = b""
        if data is not None:
            row = data[i]
            raw = bytes(row) if isinstance(row, bytes) else row.tobytes()
            payload = raw[: length[i]]
        channel = label if label is not None else bus[i]
        kwargs = dict(
            timestamp=t, arbitration_id=ident[i] & 0x1FFFFFFF, is_extended_id=bool(ide[i]),
            channel=channel, is_rx=not tx[i],
        )  # fmt: skip
        if kind == _REMOTE:
            yield can.Message(is_remote_frame=True, dlc=dlc[i], **kwargs)
        elif kind == _ERROR:
            yield can.Message(is_error_frame=True, data=payload, **kwargs)
        else:
            yield can.Message(data=payload, is_fd=bool(edl[i]), bitrate_switch=bool(brs[i]),
                              error_state_indicator=bool(esi[i]), **kwargs)  # fmt: skip


def _frame_times(comment: str) -> str | None:
    """The ``frame_times`` property of a header comment written by :func:`write_bus_log`."""
    match = re.search(r'<e name="frame_times">(\w+)</e>', comment or "")
    return match.group(1) if match else None


def _start_us(header) -> int:  # noqa: ANN001 (asammdf's HeaderBlock)
    """The header's start in µs since the epoch: UTC as stored, or a local time (no offset
    recorded) read in this machine's zone, as python-can reads it."""
    from asammdf.blocks.v4_constants import FLAG_HD_LOCAL_TIME

    if header.time_flags & FLAG_HD_LOCAL_TIME:
        return round(header.start_time.timestamp() * 1e6)
    return round(header.abs_time / 1000)


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


# -- measurements --------------------------------------------------------------------------


@dataclass
class Channel:
    """One measured quantity: its raw values, and how a tool makes them physical."""

    name: str
    raw: np.ndarray
    conversion: dict | None = None  # asammdf's conversion dict (None: the raw value is it)
    unit: str = ""
    comment: str = ""


def write_measurements(
    path: Path,
    start_us: int,
    t: np.ndarray,
    channels: list[Channel],
    *,
    group: str,
    source: str,
    source_path: str,
    comment: str,
) -> None:
    """One channel group (time ``t`` in s from ``start_us``, µs since the epoch) of
    ``channels``, each with its unit and conversion, as an MF4 (atomically)."""
    from asammdf.blocks.v4_blocks import SourceInformation
    from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_ECU

    module = asammdf()
    mdf = _new_mdf(start_us)
    root = ET.Element("HDcomment")
    ET.SubElement(root, "TX").text = comment
    mdf.header.comment = ET.tostring(root, encoding="unicode")
    info = SourceInformation(source_type=SOURCE_ECU, bus_type=BUS_TYPE_CAN)
    info.name, info.path = source, source_path
    signals = [
        module.Signal(
            samples=c.raw, timestamps=t, name=c.name, unit=c.unit, comment=c.comment,
            conversion=dict(c.conversion) if c.conversion else None, source=info,
        )
        for c in channels
    ]  # fmt: skip
    mdf.append(signals, acq_name=group, acq_source=info, comment=comment)
    with quiet():
        _save(mdf, path)
    mdf.close()
