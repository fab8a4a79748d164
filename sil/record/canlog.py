"""CAN log files: candump ``-L`` format as can-utils writes it, plus python-can's ASC and BLF,
and MF4 (ASAM MDF 4 bus logging, :mod:`sil.record.mdf`).

``(1.234567) vcan0 100#0011223344556677`` per frame; in lockstep the timestamps are simulated
time, so two runs of the same scenario and seed give byte-identical files.
"""

from __future__ import annotations

import errno
import gzip
import itertools
import logging
import re
import zlib
from collections.abc import Iterable, Iterator
from datetime import datetime
from pathlib import Path
from typing import BinaryIO, TextIO

import can
import numpy as np
from can.util import channel2int

from sil.record.results import WriteError, atomic

# python-can's readers log what they make of odd lines (a DLC that does not match the data, a
# line they skip); the readers here say what is wrong with a log themselves, in one line, so
# those records go to the application's handlers, if any, never to stderr by default
logging.getLogger("can.io").addHandler(logging.NullHandler())

EXTRA_FORMATS = ("asc", "blf", "mf4")
# what `sil log convert` writes, by the output's suffix
OUTPUT_FORMATS = {
    ".log": "candump",
    ".asc": "asc",
    ".blf": "blf",
    ".trc": "trc",
    ".csv": "csv",
    ".mf4": "mf4",
    ".mdf": "mf4",
}
_MDF_MAGIC = (b"MDF     ", b"UnFinMF ")  # an MDF file; one its logger did not finish
_HEX_DIGITS = np.frombuffer(b"0123456789ABCDEF", np.uint8)
# two upper-case hex digits per byte value
_HEX_PAIRS = np.stack([_HEX_DIGITS[np.arange(256) >> 4], _HEX_DIGITS[np.arange(256) & 15]], axis=1)
_TS_WIDTH = 20  # right-aligned "%.6f" field; the padding is taken out again


def fixed6(values: np.ndarray) -> np.ndarray | None:
    """``"%14.6f"`` of every value as a (values, 14) uint8 matrix, padded with NUL bytes, or None
    when a value is negative, not below 1e6 or too close to a rounding tie to be sure (then
    %-formatting decides). Exact: x * 1e6 is within 1e-4 of the true product below 1e6, so the
    nearest integer is %.6f's rounding unless the fraction is near one half."""
    scaled = values * 1e6
    if not len(values) or not (values >= 0).all() or not (values < 1e6).all():
        return None if len(values) else np.zeros((0, 14), np.uint8)
    fraction = scaled - np.floor(scaled)
    if (np.abs(fraction - 0.5) < 0.01).any():
        return None
    digits = _decimal_digits(np.floor(scaled + 0.5).astype(np.int64), 13)  # 7 + 6
    out = np.empty((len(values), 14), np.uint8)
    out[:, :7] = digits[:, :7] + 48
    out[:, 7] = ord(".")
    out[:, 8:] = digits[:, 7:] + 48
    # leading zeros of the seconds are padding, but one digit always stays
    lead = np.cumsum(digits[:, :6] != 0, axis=1) == 0
    out[:, :6][lead] = 0
    return out


def _decimal_digits(values: np.ndarray, count: int) -> np.ndarray:
    """The last ``count`` decimal digits of non-negative integers, most significant first, as a
    (values, count) matrix: one division by ten per digit (by a scalar, fast in numpy)."""
    digits = np.empty((count, len(values)), np.int64)
    for j in range(count - 1, -1, -1):
        quotient = values // 10
        digits[j] = values - quotient * 10
        values = quotient
    return digits.T


class CandumpWriter:
    """Writes frames in candump -L format; flushes often so a killed run keeps what it had."""

    def __init__(self, path: Path, channel: str = "vcan0", flush_every: int = 256) -> None:
        self.path = path
        self.channel = channel
        self.flush_every = flush_every
        self.frames = 0
        self._file: TextIO = path.open("w", encoding="ascii", newline="\n")

    def write(self, timestamp_s: float, frame_id: int, data: bytes | bytearray) -> None:
        line = f"({timestamp_s:.6f}) {self.channel} {frame_id:03X}#{data.hex().upper()}\n"
        self._file.write(line)
        self.frames += 1
        if self.frames % self.flush_every == 0:
            self._file.flush()

    def write_many(
        self,
        timestamps_s: np.ndarray,
        frame_ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
    ) -> None:
        """Many frames at once, byte for byte as :meth:`write` one by one.

        ``payload`` is (frames, 8) uint8, zero beyond each frame's ``lengths`` (0..8). The lines
        are laid out as a character matrix with a fixed-width field per part, padded with NUL
        bytes that are taken out at the end; only the timestamps go through %-formatting (one
        call for all of them).
        """
        n = len(frame_ids)
        if n == 0:
            return
        fast = fixed6(timestamps_s)
        ts_text = (
            "" if fast is not None else (f"%{_TS_WIDTH}.6f" * n) % tuple(timestamps_s.tolist())
        )
        if fast is None and len(ts_text) != _TS_WIDTH * n:  # wider than the field: one by one
            for t, i, d, k in zip(
                timestamps_s.tolist(), frame_ids.tolist(), payload, lengths.tolist(), strict=True
            ):
                self.write(t, i, bytes(d[:k]))
            return
        ids = frame_ids.astype(np.int64)
        head = b") " + self.channel.encode("ascii") + b" "
        w_ts, w_head = _TS_WIDTH, len(head)
        width = 1 + w_ts + w_head + 8 + 1 + 16 + 1
        m = np.zeros((n, width), np.uint8)
        m[:, 0] = ord("(")
        if fast is not None:
            m[:, 1 + w_ts - 14 : 1 + w_ts] = fast
        else:
            ts = np.frombuffer(ts_text.encode("ascii"), np.uint8).reshape(n, w_ts)
            m[:, 1 : 1 + w_ts] = np.where(ts == 32, 0, ts)
        c = 1 + w_ts
        m[:, c : c + w_head] = np.frombuffer(head, np.uint8)
        c += w_head
        # the ID as "%03X": eight hex digits, leading zeros dropped down to three
        digits = (ids[:, None] >> np.arange(28, -4, -4)) & 15
        n_digits = 1 + (ids[:, None] >= 16 ** np.arange(1, 8)).sum(axis=1)
        keep = np.arange(8) >= 8 - np.maximum(3, n_digits)[:, None]
        m[:, c : c + 8] = np.where(keep, _HEX_DIGITS[digits], 0)
        c += 8
        m[:, c] = ord("#")
        c += 1
        hexed = _HEX_PAIRS[payload].reshape(n, 16)
        m[:, c : c + 16] = np.where(np.arange(16) < 2 * lengths[:, None], hexed, 0)
        m[:, c + 16] = ord("\n")
        self._file.write(m[m != 0].tobytes().decode("ascii"))
        before = self.frames
        self.frames += n
        if self.frames // self.flush_every != before // self.flush_every:
            self._file.flush()

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def convert(candump_path: Path, fmt: str, start_s: float | None = None) -> Path:
    """Write a copy of a candump log as ASC, BLF or MF4 (:func:`convert_log`), all starting at
    ``start_s`` (default: :func:`sil.record.mdf.log_start`): the MF4's header and time channel
    from it, the ASC's and BLF's frames at their absolute times; atomically
    (:func:`sil.record.results.atomic`: a full disk leaves no part of a copy)."""
    if fmt not in EXTRA_FORMATS:
        raise ValueError(f"log format '{fmt}' is not one of {', '.join(EXTRA_FORMATS)}")
    from sil.record.mdf import MdfUnavailable

    target = candump_path.with_suffix(f".{fmt}")
    try:
        convert_log(candump_path, target, start_s=start_s)
    except (LogReadError, MdfUnavailable) as exc:  # (nothing written): as a write error
        raise WriteError(target, OSError(errno.EIO, str(exc))) from None
    return target


class LogReadError(Exception):
    """A log that could not be read to its end; names the file and the position."""

    def __init__(self, path: Path, position: str, reason: str, frames_read: int) -> None:
        super().__init__(f"{path}: {position}: {reason} (after {frames_read} frames)")
        self.path, self.position, self.reason, self.frames_read = (
            path,
            position,
            reason,
            frames_read,
        )


_CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"


def detect_format(path: Path) -> tuple[str, bool]:
    """The log format from the file's content (not its name), and whether it is gzipped."""
    with path.open("rb") as f:
        head = f.read(65536)
    gz = head[:2] == b"\x1f\x8b"
    if gz:  # what the head decompresses to (a gzip file cut short fails later, at its end)
        try:
            head = zlib.decompressobj(wbits=31).decompress(head, 4096)
        except zlib.error as exc:
            raise LogReadError(path, "byte 0", f"corrupt gzip data: {exc}", 0) from None
    if head[:8] in _MDF_MAGIC:
        version = head[8:16].decode("latin-1").strip()
        if not version.startswith("4"):
            reason = f"MDF {version or '(no version)'}: a CAN bus log is MDF 4 (MF4)"
            raise LogReadError(path, "byte 8", reason, 0)
        return "mf4", gz
    if head[:4] == b"LOGG":
        return "blf", gz
    text = head.decode("latin-1")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not lines:
        raise LogReadError(path, "line 1", "empty file: no format to recognise", 0)
    first = lines[0]
    if first.startswith(";$FILEVERSION") or (first.startswith(";") and "PCAN" in text):
        return "trc", gz
    if first.lower().startswith(_CSV_HEADER):
        return "csv", gz
    if _CANDUMP.match(first):
        return "candump", gz
    if first.startswith("date ") or any(
        ln.startswith(("base hex", "base dec", "Begin Trigger")) for ln in lines[:8]
    ):
        return "asc", gz
    raise LogReadError(path, "line 1", f"unrecognised log format (starts with {first[:40]!r})", 0)


_CANDUMP = re.compile(r"^\((\d+\.\d+)\)\s+(\S+)\s+([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#(\S*)")


class _CountingText:
    """A text file handed out line by line (an iterator), counting the lines for error positions.
    With ``require_eol`` a last line without its end of line is a record cut short (an ASC
    file's closing ``End TriggerBlock`` excepted); without, the format's parser must tell."""

    def __init__(self, f: TextIO, require_eol: bool = True) -> None:
        self._f = f  # opened with newline="": the ends of line as written
        self._require_eol = require_eol
        self.line = 0
        self.last = ""  # the last line that was not blank, stripped
        self._crlf: bool | None = None  # the file's lines end with CR LF (its first line's do)
        self._half_end = False  # the last line read ends with CR where the others have CR LF
        self.unterminated = False  # the last line read has no end of line
        self.read: list[tuple[int, str]] | None = None  # when a list: (number, text) of each line

    def __iter__(self) -> _CountingText:
        return self

    def __next__(self) -> str:
        line = self.readline()
        if not line:
            raise StopIteration
        return line

    def readline(self) -> str:
        line = self._f.readline()
        if not line:
            if self._half_end:
                raise ValueError(f"last line cut short (CR without LF): {self.last[:60]!r}")
            return line
        self.line += 1
        self.unterminated = not line.endswith(("\n", "\r"))
        if self.read is not None:
            self.read.append((self.line, line.strip()))
        if not self._require_eol:
            self.last = line.strip() or self.last
            return line
        if self._crlf is None and line.endswith(("\n", "\r")):
            self._crlf = line.endswith("\r\n")
        self._half_end = bool(self._crlf) and line.endswith("\r")
        text = line.strip()
        if text:
            self.last = text
        if not line.endswith(("\n", "\r")) and text.lower() != _ASC_END:
            raise ValueError(f"last line cut short (no end of line): {line[:60]!r}")
        return line

    def __getattr__(self, name):
        return getattr(self._f, name)


_ASC_END = "end triggerblock"
# an ASC header's dates: "date Sun Dec 06 21:56:41.641 2026", "Begin Triggerblock Sun Dec ..."
_ASC_DATE = re.compile(r"^(date|begin\s+triggerblock)\s+\w+\s+(.+)$", re.IGNORECASE)


# the TRC record types that carry a frame (PEAK's format: data, CAN FD, remote; Rx and Tx in
# versions 1.1 and 1.3); python-can reads these and skips the others (status, error, event)
_TRC_FRAME_TYPES = frozenset({"DT", "FD", "FB", "FE", "BI", "RR", "Rx", "Tx"})


class _BadLine(ValueError):
    """A line found bad after later lines were read: ``line`` is its number."""

    def __init__(self, line: int, reason: str) -> None:
        super().__init__(reason)
        self.line = line


def _trc_skipped(reader: can.TRCReader, text: str) -> bool:
    """A whole TRC line that holds no frame, as python-can skips it: a comment, or a record of
    another type (version 1.0, which has no type column: its bus information line)."""
    if not text or text.startswith(";"):
        return True
    cols = text.split()
    version = reader.file_version.name
    if version in ("V2_0", "V2_1"):
        index = reader.columns.get("T")
    else:
        index = {"V1_1": 2, "V1_3": 3}.get(version)
    if index is None:
        return version not in ("V2_0", "V2_1") and len(cols) > 2 and cols[2] == "FFFFFFFF"
    return len(cols) > index and cols[index] not in _TRC_FRAME_TYPES


def _trc_frames(f: _CountingText) -> Iterator[can.Message]:
    """python-can's TRC reader, but a line it cannot parse is an error, not a line dropped (it
    drops, with a logged warning, a record with a column missing). PEAK's own tools end a file
    without an end of line, so a last line without one must be a whole record: a record cut
    short lacks its last columns (or some data bytes, which :func:`_check_length` finds), and a
    line of a type python-can skips is no record. The reader takes one line for each record,
    so every line read before a frame's own, since the last frame, must be one it skips."""
    f.read = read = []
    reader = can.TRCReader(f)
    frames = iter(reader)
    while True:
        try:
            message = next(frames, None)
        except ValueError as exc:
            text = read[-1][1] if read else ""
            if _trc_skipped(reader, text):
                raise
            raise ValueError(f"not a whole TRC record ({exc}): {text[:60]!r}") from None
        for number, text in read if message is None else read[:-1]:
            if not _trc_skipped(reader, text):
                raise _BadLine(number, f"not a whole TRC record (a column missing): {text[:60]!r}")
        read.clear()
        if message is None:
            return
        yield message


def _candump_frames(f: _CountingText):
    for line in f:
        text = line.strip()
        if not text:
            continue
        m = _CANDUMP.match(text)
        if m is None:
            raise ValueError(f"not a candump -L line: {text[:60]!r}")
        ts, channel, ident, payload = m.groups()
        can_id = int(ident, 16)
        if len(ident) == 8 and can_id & 0x20000000:
            yield can.Message(
                timestamp=float(ts),
                channel=channel,
                is_error_frame=True,
                arbitration_id=can_id & 0x1FFFFFFF,
            )
            continue
        extended = len(ident) == 8
        if payload.startswith("#"):  # CAN FD: ID##<flags><data>
            data = bytes.fromhex(payload[2:])
            yield can.Message(
                timestamp=float(ts),
                channel=channel,
                arbitration_id=can_id,
                is_extended_id=extended,
                is_fd=True,
                data=data,
            )
        elif payload.upper().startswith("R"):
            yield can.Message(
                timestamp=float(ts),
                channel=channel,
                arbitration_id=can_id,
                is_extended_id=extended,
                is_remote_frame=True,
            )
        else:
            data = bytes.fromhex(payload)
            if len(data) > 8:
                raise ValueError(f"{len(data)} data bytes in a classical CAN frame")
            yield can.Message(
                timestamp=float(ts),
                channel=channel,
                arbitration_id=can_id,
                is_extended_id=extended,
                data=data,
            )


def _check_length(message: can.Message) -> None:
    """A classical data frame's bytes must be as many as its DLC says (python-can's text readers
    take both as written)."""
    if message.is_fd or message.is_remote_frame or message.is_error_frame:
        return
    if message.dlc != len(message.data):
        raise ValueError(f"{len(message.data)} data bytes for DLC {message.dlc}")


class LogReader:
    """Every frame of a log (candump -L, ASC, BLF, TRC, python-can CSV or MF4, optionally
    gzipped), with the position of the last one handed out (:attr:`position`).

    A truncated or corrupt file raises :class:`LogReadError` naming the line (text formats) or
    byte offset (BLF, MF4) where reading failed, once the frames before it have been handed out:
    a last line cut short (no end of line), a line that is not a record of the format, an ASC
    file without its closing ``End TriggerBlock``, a gzip stream or BLF file that ends early, an
    MF4 whose blocks do not all lie in the file (:class:`sil.record.mdf.BusLogReader`).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.frames = 0
        self.format: str | None = None  # once reading began
        self.mf4 = None  # the MF4 reader (its start and time base), once reading began
        self._text: _CountingText | None = None
        self._gz = False

    @property
    def position(self) -> str:
        """The last frame's line (text formats) or its number in the file (BLF, MF4)."""
        return f"line {self._text.line}" if self._text is not None else f"frame {self.frames}"

    @property
    def header_start_s(self) -> float | None:
        """The wall-clock start an ASC file's header gives (its times count from it: the date
        of its ``Begin Triggerblock``, else of its ``date`` line), once reading began; None for
        the other formats or when there is none."""
        if self.format != "asc":
            return None
        opener = gzip.open if self._gz else open
        dates: dict[str, str] = {}
        with opener(self.path, "rt", encoding="latin-1") as f:
            for line in itertools.islice(f, 200):
                match = _ASC_DATE.match(line.strip())
                if match:
                    dates.setdefault(" ".join(match.group(1).lower().split()), match.group(2))
                if "begin triggerblock" in dates:
                    break
        for key in ("begin triggerblock", "date"):
            if key in dates:
                try:
                    return can.ASCReader._datetime_to_timestamp(dates[key])
                except ValueError:
                    pass
        return None

    def __iter__(self) -> Iterator[can.Message]:
        fmt, gz = detect_format(self.path)
        self.format, self._gz = fmt, gz
        if fmt == "mf4":
            return self._mf4(gz)
        return self._blf(gz) if fmt == "blf" else self._text_frames(fmt, gz)

    def _error(self, position: str, reason: str) -> LogReadError:
        return LogReadError(self.path, position, reason, self.frames)

    def _mf4(self, gz: bool) -> Iterator[can.Message]:
        from sil.record.mdf import BusLogReader, MdfUnavailable

        self.mf4 = reader = BusLogReader(self.path, gz)
        try:
            for message in reader:
                self.frames += 1
                yield message
        except MdfUnavailable as exc:
            raise self._error("byte 0", str(exc)) from None

    def _blf(self, gz: bool) -> Iterator[can.Message]:
        raw = gzip.open(self.path, "rb") if gz else self.path.open("rb")
        try:
            reader = can.BLFReader(_KeptOpen(raw))
            for message in reader:
                self.frames += 1
                yield message
            if gz:
                raw.read()  # to the end: a gzip stream cut short fails its check there
            size = raw.tell() if gz else self.path.stat().st_size
        except Exception as exc:  # python-can raises struct.error, BLFParseError, zlib.error
            where = "unknown byte" if raw.closed else f"byte {raw.tell()}"
            where += " (decompressed)" if gz and not raw.closed else ""
            what = "truncated gzip data" if isinstance(exc, EOFError) else "corrupt BLF"
            raise self._error(where, f"{what}: {exc}") from None
        finally:
            raw.close()
        if size < reader.file_size:  # python-can stops quietly at a short file
            raise self._error(
                f"byte {size}", f"truncated BLF: the header says {reader.file_size} bytes"
            )

    def _text_frames(self, fmt: str, gz: bool) -> Iterator[can.Message]:
        path = self.path
        opener = gzip.open if gz else open
        text = opener(path, "rt", encoding="latin-1", newline="")
        counted = self._text = _CountingText(text, require_eol=fmt != "trc")
        try:
            if fmt == "candump":
                frames = _candump_frames(counted)
            elif fmt == "trc":
                frames = _trc_frames(counted)
            else:
                reader = {"asc": can.ASCReader, "csv": can.CSVReader}[fmt]
                frames = iter(reader(counted))
            frame_line = 0  # the line of the last frame
            check = fmt != "candump"  # (a candump frame's DLC is its data's length)
            for message in frames:
                if check:
                    _check_length(message)
                self.frames += 1
                frame_line = counted.line
                yield message
            if fmt == "asc" and counted.last.lower() != _ASC_END:
                raise ValueError("truncated ASC: it ends without 'End TriggerBlock'")
            if counted.unterminated and frame_line != counted.line:
                raise ValueError(f"last line cut short (no end of line): {counted.last[:60]!r}")
        except (ValueError, IndexError, KeyError, EOFError, OSError) as exc:
            reason = str(exc) or type(exc).__name__
            if isinstance(exc, EOFError):
                reason = f"truncated gzip data: {reason}"
            line = exc.line if isinstance(exc, _BadLine) else counted.line
            raise self._error(f"line {line}", reason) from None
        finally:
            text.close()


class _KeptOpen:
    """A binary file that a reader's ``close`` leaves open (python-can's readers close their file
    at the end; what remains is checked after them)."""

    def __init__(self, f: BinaryIO) -> None:
        self._f = f

    def close(self) -> None:
        pass

    def __getattr__(self, name):
        return getattr(self._f, name)


def read_frames(path: Path) -> LogReader:
    """Every frame of a log: see :class:`LogReader`."""
    return LogReader(path)


# -- writing any format, and converting ----------------------------------------------------

_CAN_ERR_FLAG = 0x20000000  # an error frame's ID in candump (linux/can/error.h)


def candump_line(msg: can.Message) -> str:
    """A frame as ``candump -L`` writes it (a data frame as :class:`CandumpWriter` does; a
    number for a channel becomes ``canN``)."""
    channel = msg.channel if msg.channel is not None else "can0"
    if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
        channel = f"can{channel}"
    head = f"({msg.timestamp:.6f}) {channel} "
    data = bytes(msg.data or b"").hex().upper()
    if msg.is_error_frame:
        return f"{head}{_CAN_ERR_FLAG | msg.arbitration_id:08X}#{data}\n"
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    if msg.is_remote_frame:
        return f"{head}{ident}#R\n"
    if msg.is_fd:
        flags = (1 if msg.bitrate_switch else 0) | (2 if msg.error_state_indicator else 0)
        return f"{head}{ident}##{flags:X}{data}\n"
    return f"{head}{ident}#{data}\n"


class _AscWriter(can.ASCWriter):
    """python-can's ASC writer with the header's milliseconds in three digits, as CANoe reads
    them: python-can writes 85 ms as ".85", which any reader (python-can's too) takes as 850."""

    def _format_header_datetime(self, dt: datetime) -> str:
        return dt.strftime(f"%a %b %d %H:%M:%S.{dt.microsecond // 1000:03d} %Y")


CHANNELS_MAX = 64  # a channel number kept as it is below this; others numbered from 0


def numbered_channels(frames: Iterable[can.Message]) -> Iterator[can.Message]:
    """``frames`` with each channel as a number, for the formats that number their channels
    (ASC, BLF, TRC): a channel that names a small number keeps it (``vcan0``, ``can1``, 2), any
    other (a group address, a name) takes the lowest number no channel holds yet, in order of
    appearance; a frame without a channel stays so (the format's first)."""
    numbers: dict[object, int] = {}
    for msg in frames:
        channel = msg.channel
        if channel is not None:
            number = numbers.get(channel)
            if number is None:
                own = channel2int(channel)
                taken = set(numbers.values())
                if own is None or not 0 <= own < CHANNELS_MAX or own in taken:
                    own = next(k for k in itertools.count() if k not in taken)
                number = numbers[channel] = own
            msg.channel = number
        yield msg


def write_log(path: Path, frames: Iterable[can.Message], fmt: str, shift_s: float = 0.0) -> int:
    """Write ``frames`` (their times plus ``shift_s``) as a candump, ASC, BLF, TRC or python-can
    CSV log, atomically; the frames written."""
    count = 0
    with atomic(path) as tmp:
        if fmt == "candump":
            with tmp.open("w", encoding="ascii", newline="\n") as f:
                for msg in frames:
                    msg.timestamp += shift_s
                    f.write(candump_line(msg))
                    count += 1
            return count
        writers = {"asc": _AscWriter, "blf": can.BLFWriter, "trc": can.TRCWriter,
                   "csv": can.CSVWriter}  # fmt: skip
        writer = writers[fmt](str(tmp))
        if fmt != "csv":
            frames = numbered_channels(frames)
        try:
            for msg in frames:
                msg.timestamp += shift_s
                writer.on_message_received(msg)
                count += 1
        finally:
            writer.stop()
    return count


def output_format(path: Path) -> str:
    """The format `sil log convert` writes to ``path``, by its suffix; ValueError naming them."""
    fmt = OUTPUT_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(
            f"{path}: no log format for the suffix '{path.suffix}' (one of "
            f"{', '.join(OUTPUT_FORMATS)})"
        )
    return fmt


def convert_log(source: Path, target: Path, *, start_s: float | None = None) -> dict:
    """Convert a log of any format :class:`LogReader` reads into the format ``target``'s suffix
    names (:data:`OUTPUT_FORMATS`), keeping its absolute start (:mod:`sil.record.mdf`):

    - to MF4: the header holds the start (``start_s``, else the MF4's own, else epoch times'
      first frame, else :func:`sil.record.mdf.log_start`) and the time channel counts from it;
    - to candump or CSV: the source's times (a run's simulated time stays so, epoch times
      stay epoch times);
    - to ASC, BLF or TRC, whose headers carry a date: epoch times.

    What the conversion did (frames, formats, start); LogReadError for a source that cannot be
    read to its end (nothing is written), ValueError for a target of no known format,
    :class:`sil.record.mdf.MdfUnavailable` without asammdf, WriteError for a target not written."""
    from sil.record import mdf

    fmt = output_format(target)
    reader = read_frames(source)
    frames = iter(reader)
    first = next(frames, None)
    stream = itertools.chain([first], frames) if first is not None else iter(())
    first_s = first.timestamp if first is not None else None
    if reader.format == "mf4":  # its own start; frames before 1973 count from it (python-can's
        own = reader.mf4  # logconvert of a run's log: its axis near -1.8e9 s, which this undoes)
        relative = own.relative or (first_s is not None and first_s < mdf.EPOCH_FROM_S)
        start = (start_s, "--start") if start_s is not None else (own.start_us / 1e6, "the MF4")
        base = mdf.TimeBase(round(start[0] * 1e6), relative, start[1])
    else:
        base = mdf.time_base(first_s, start_s, lambda: mdf.log_start(source, reader.header_start_s))
    if fmt == "mf4":
        table = mdf.FrameTable.of(stream)
        mdf.write_bus_log(target, table, base, note=f"from {source.name}")
        count = len(table)
    else:
        shift = base.start_s if fmt in ("asc", "blf", "trc") and base.relative else 0.0
        count = write_log(target, stream, fmt, shift)
    return {
        "source": str(source),
        "source_format": reader.format,
        "target": str(target),
        "target_format": fmt,
        "frames": count,
        "start": base.iso(),
        "start_from": base.origin,
        "source_times": "from the start" if base.relative else "epoch",
    }
