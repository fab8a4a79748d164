"""trace.csv: every DBC signal per tick, decoded in bulk from the frames the recorder writes.

One row per tick: its time and tick, the command, the true and measured speed in %N, then every
payload signal of every message at its latest value (sample-and-hold). The frames of a chunk are
decoded per message by shifts and masks on their 64-bit words (the vectorised
``MessageCodec.unpack``); each trace cell is an index into the values decoded, and each distinct
value is %-formatted once.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import TextIO

import numpy as np

from protocol.codec import Codec
from sil.record.canlog import fixed6

N_MAX_RPM = 112_500.0
_SKIP = ("_CRC", "_Counter")
_CELL = 16  # "%15.9g," per trace cell (%.9g takes at most 15); the padding is taken out again
_PREFIX_TIME, _PREFIX_TICK = 21, 11  # "%20.6f," and "%10d,"


class _Group:
    """Frames of one message (or one multiplexer index) and the trace columns they set."""

    __slots__ = ("columns", "fields", "single")

    def __init__(self, columns: list[int], fields: list[tuple]) -> None:
        self.columns = np.array(columns, np.intp)
        self.fields = fields  # (start, mask, sign bit, scale, offset) per column
        self.single = True  # no other group writes these columns


class TraceWriter:
    """The trace of a run, written chunk by chunk: :meth:`write_rows` decodes a chunk's frames and
    writes the rows that end among them; the values at its end carry into the next chunk."""

    def __init__(
        self, path: Path, codec: Codec, period_s: float, commands: np.ndarray | None
    ) -> None:
        self.codec = codec
        self.period_s = period_s
        # per frame ID, its message's length: frames of another length are not decoded
        self._lengths = {message.frame_id: message.length for message in codec.messages}

        # trace columns: every payload signal of every message, with its unit
        self._columns: dict[str, int] = {}
        units: list[str] = []
        for message in codec.messages:
            layouts = (
                [message.mux_layout, *message.mux_signals.values()]
                if message.multiplexed
                else list(message.signals)
            )
            for layout in layouts:
                if not layout.name.endswith(_SKIP) and layout.name not in self._columns:
                    self._columns[layout.name] = len(units)
                    units.append(layout.unit)
        names = list(self._columns)
        self._build_groups()
        self._carry = np.full(len(names), math.nan)  # the latest value of every column
        self.path = path
        self._file: TextIO = path.open("w", newline="")
        header = ["time[s]", "tick[-]", "command[%N or V]", "speed_true[%]", "speed_meas[%]"]
        header += [f"{n}[{u or '-'}]" for n, u in zip(names, units, strict=True)]
        self._file.write(",".join(header) + "\n")
        # one preformatted row, for rows the bulk path cannot lay out
        self._row_format = "%.6f,%d,%.9g,%.9g,%.9g," + ",".join(["%.9g"] * len(names)) + "\n"
        self._commands = np.asarray(commands, np.float64) if commands is not None else np.zeros(0)

    def _build_groups(self) -> None:
        self._groups: dict[int, _Group] = {}  # plain messages by frame ID
        self._mux: dict[int, tuple[tuple, dict[int, _Group]]] = {}
        writers: Counter[int] = Counter()

        def field(layout) -> tuple:
            sign_bit = 1 << (layout.length - 1) if layout.signed else 0
            return (
                layout.start,
                (1 << layout.length) - 1,
                sign_bit,
                layout.scale,
                layout.offset,
            )

        all_groups: list[_Group] = []
        for message in self.codec.messages:
            if message.multiplexed:
                by_index = {}
                for index, layout in message.mux_signals.items():
                    g = _Group([self._columns[layout.name]], [field(layout)])
                    by_index[index] = g
                    all_groups.append(g)
                self._mux[message.frame_id] = (field(message.mux_layout), by_index)
            else:
                g = _Group(
                    [self._columns[n] for n in message.signal_names],
                    [field(layout) for layout in message.signals],
                )
                self._groups[message.frame_id] = g
                all_groups.append(g)
        for g in all_groups:
            writers.update(g.columns.tolist())
        for g in all_groups:
            g.single = all(writers[c] == 1 for c in g.columns.tolist())

    @property
    def closed(self) -> bool:
        return self._file.closed

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def write_rows(
        self,
        ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
        no_decode: list[int],
        row_ticks: np.ndarray,
        row_pos: np.ndarray,
        done: int,
    ) -> None:
        """The rows of a chunk: its frames (``payload`` (frames, 8), zero beyond ``lengths``),
        ``done`` frames written before it, those at the indices ``no_decode`` not decoded; row i
        at tick ``row_ticks[i]``, after the frames before ``row_pos[i]`` (from the run's start)."""
        n = len(ids)
        ncols = len(self._carry)
        # rows plus one at the chunk's end (the values carried into the next chunk)
        pos = np.append(np.asarray(row_pos, np.int64), done + n) - done
        nrows = len(pos)
        # the values pool: the carried values first, then every decoded value; each cell of the
        # trace is an index into it
        pool = [self._carry]
        pool_size = ncols
        cell = np.broadcast_to(np.arange(ncols), (nrows, ncols)).copy()
        best = None  # per cell, the write index of the frame that set it (columns with several)

        decodable = np.zeros(n, bool)
        if n:
            lengths_ok = lengths == 8
            for frame_id, length in self._lengths.items():
                if length != 8:
                    lengths_ok |= (ids == frame_id) & (lengths == length)
            decodable = lengths_ok
            if no_decode:
                decodable[no_decode] = False
            words = payload.view("<u8").ravel() if n else np.zeros(0, np.uint64)

        def place(group: _Group, at: np.ndarray, values: np.ndarray) -> None:
            nonlocal pool_size, best
            k = len(at)
            pool.append(values.ravel())
            index = np.searchsorted(at, pos, "left") - 1  # the last frame before each row
            width = len(group.columns)
            source = pool_size + index[:, None] * width + np.arange(width)
            pool_size += k * width
            hit = index >= 0
            if group.single:
                cols = group.columns
                cell[:, cols] = np.where(hit[:, None], source, cell[:, cols])
            else:
                if best is None:
                    best = np.full((nrows, ncols), -1, np.int64)
                where = np.where(hit, at[np.maximum(index, 0)], -1)
                for j, c in enumerate(group.columns.tolist()):
                    take = where > best[:, c]
                    cell[take, c] = source[take, j]
                    best[take, c] = where[take]

        if n and decodable.any():
            for frame_id, group in self._groups.items():
                at = np.flatnonzero(decodable & (ids == frame_id))
                if len(at):
                    place(group, at, _decode(words[at], group.fields))
            for frame_id, (mux_field, by_index) in self._mux.items():
                at = np.flatnonzero(decodable & (ids == frame_id))
                if not len(at):
                    continue
                start, mask = mux_field[0], mux_field[1]
                index = ((words[at] >> np.uint64(start)) & np.uint64(mask)).astype(np.int64)
                mux_values = _decode(words[at], [mux_field])[:, 0]
                for value in np.unique(index).tolist():
                    group = by_index.get(value)
                    if group is None:
                        name = self.codec.by_id[frame_id].name
                        raise ValueError(f"{name}: no signal for multiplexer index {value}")
                    sel = at[index == value]
                    # the column is chosen by the multiplexer's physical value, as unpack() does
                    physical = mux_values[index == value]
                    if not np.all(physical == value):
                        continue
                    place(group, sel, _decode(words[sel], group.fields))

        values = np.concatenate(pool) if len(pool) > 1 else self._carry
        final = cell[-1]
        self._carry = values[final].copy()
        if nrows == 1:
            return
        cell = cell[:-1]
        ticks = np.asarray(row_ticks, np.int64)
        c = self._columns
        true = values[cell[:, c["TrueSpeed"]]]
        meas = values[cell[:, c["ShaftSpeed"]]]
        commands = self._commands
        if len(commands):
            command = np.where(
                ticks < len(commands), commands[np.minimum(ticks, len(commands) - 1)], math.nan
            )
        else:
            command = np.full(len(ticks), math.nan)
        extra = np.concatenate([command, 100.0 * true / N_MAX_RPM, 100.0 * meas / N_MAX_RPM])
        m = len(ticks)
        size = len(values)
        cell = np.concatenate(
            [size + np.arange(3)[None, :] * m + np.arange(m)[:, None], cell], axis=1
        )
        values = np.concatenate([values, extra])
        self._file.write(self._format_rows(ticks, values, cell))

    def _format_rows(self, ticks: np.ndarray, values: np.ndarray, cell: np.ndarray) -> str:
        """Rows of "%.6f,%d,%.9g,...\n", each distinct value formatted once."""
        m, width = cell.shape
        times = ticks * self.period_s
        distinct, inverse = np.unique(values.view(np.int64), return_inverse=True)
        text = (f"%{_CELL - 1}.9g," * len(distinct)) % tuple(distinct.view(np.float64).tolist())
        fast_times = fixed6(times)  # "%.6f" without %-formatting, when sure
        time_text = (
            (f"%{_PREFIX_TIME - 1}.6f," * m) % tuple(times.tolist())
            if fast_times is None
            else " " * (_PREFIX_TIME * m)
        )
        tick_text = (f"%{_PREFIX_TICK - 1}d," * m) % tuple(ticks.tolist())
        if (
            len(text) != _CELL * len(distinct)
            or len(time_text) != _PREFIX_TIME * m
            or len(tick_text) != _PREFIX_TICK * m
        ):  # a field wider than its place: row by row
            rows = values[cell]
            return "".join(
                self._row_format % (t, k, *r)
                for t, k, r in zip(times.tolist(), ticks.tolist(), rows.tolist(), strict=True)
            )
        strings = np.frombuffer(text.encode("ascii"), np.uint64).reshape(-1, _CELL // 8)
        row_width = _PREFIX_TIME + _PREFIX_TICK + width * _CELL
        out = np.empty((m, row_width), np.uint8)
        if fast_times is None:
            out[:, :_PREFIX_TIME] = np.frombuffer(time_text.encode("ascii"), np.uint8).reshape(
                m, -1
            )
        else:
            out[:, : _PREFIX_TIME - 15] = 32
            out[:, _PREFIX_TIME - 15 : _PREFIX_TIME - 1] = np.where(fast_times == 0, 32, fast_times)
            out[:, _PREFIX_TIME - 1] = ord(",")
        out[:, _PREFIX_TIME : _PREFIX_TIME + _PREFIX_TICK] = np.frombuffer(
            tick_text.encode("ascii"), np.uint8
        ).reshape(m, -1)
        body = out[:, _PREFIX_TIME + _PREFIX_TICK :]
        body.view(np.uint64).reshape(m, width, _CELL // 8)[:] = strings[inverse.ravel()[cell]]
        out[:, -1] = ord("\n")
        return out[out != 32].tobytes().decode("ascii")


def raw_field(words: np.ndarray, start: int, mask: int, sign_bit: int) -> np.ndarray:
    """One signal's raw values (int64) in 64-bit little-endian frame words (the vectorised
    MessageCodec.unpack_raw of one field)."""
    raw = ((words >> np.uint64(start)) & np.uint64(mask)).astype(np.int64)
    return np.where(raw & sign_bit, raw - (sign_bit << 1), raw) if sign_bit else raw


def _decode(words: np.ndarray, fields: list[tuple]) -> np.ndarray:
    """Physical values (frames, signals) of 64-bit little-endian frame words."""
    out = np.empty((len(words), len(fields)), np.float64)
    for j, (start, mask, sign_bit, scale, offset) in enumerate(fields):
        out[:, j] = raw_field(words, start, mask, sign_bit).astype(np.float64) * scale + offset
    return out
