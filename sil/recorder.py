"""The recorder: every frame into ``can.log``, every signal per tick into ``trace.csv``.

It hears the whole bus (or is handed the frames in-process), checks E2E on every protected
message in the order the frames arrived, counts bits for the bus load, and keeps, sample-and-hold,
the latest value of every DBC signal; the trace gets one row per tick.

In lockstep, frames from different senders may reach the recorder in either order (the kernel
delivers one multicast frame to each listener in turn, and a fast ECU can answer before the
recorder has read the frame it answers). Each sender's own frames keep their order, so the
recorder sorts every frame into its tick: the plant's frames up to and including PlantSensors(k),
the command node's frames sent on PlantSensors(k), then the ECU's frames up to and including
EcuActuator(k). A tick is written once both ends are in, in that canonical order, stamped with
simulated time (the tick's start plus 10 us per frame). The log is therefore the same however
the frames interleaved. In real time the frames are written as they come, with wall-clock stamps.
Files are flushed chunk by chunk (every ``CHUNK_ROWS`` ticks, every 100 in real time), and
whatever is pending is written at close, so an aborted run keeps what it recorded.

Cost per frame: ``record`` does only what must happen as the frame arrives (tick bookkeeping,
sorting into its tick, which the command node reads back) and appends the frame to the chunk;
each chunk is then checked and written in bulk with numpy: E2E (table CRC-8), tick sequences,
unknown IDs and bit counts in arrival order; the can.log lines as a character matrix; the
signals decoded by shifts and masks per message; the trace cells sample-and-hold by position,
each distinct value %-formatted once. ``e2e``, ``unknown_ids`` and the tick trackers check the
frames still pending when read; ``bits`` is complete after close.
"""

from __future__ import annotations

import math
import signal
import threading
from collections import Counter
from pathlib import Path
from typing import TextIO

import numpy as np

from protocol.busload import BitCounter
from protocol.codec import Codec
from protocol.e2e import COUNTER_MODULO, E2EStatus, crc8_rows, data_id_crc_start
from protocol.lockstep import TICK_MODULO, TickTracker
from sil.canlog import CandumpWriter, fixed6

N_MAX_RPM = 112_500.0
_FRAME_SPACING_S = 10e-6
_SKIP = ("_CRC", "_Counter")
SENSORS, ACTUATOR = 0x100, 0x110
PLANT_IDS = frozenset((0x100, 0x101, 0x300, 0x301))
ECU_IDS = frozenset((0x110, 0x200, 0x210))
CHUNK_ROWS = 2048  # trace rows (ticks) per bulk write (20 s simulated at 100 Hz)
WALL_CLOCK_CHUNK_ROWS = 100  # in real time: on disk at least every 100 ECU periods
_CHUNK_FRAMES = 32768  # frames heard per bulk write when no rows come
_CELL = 16  # "%15.9g," per trace cell (%.9g takes at most 15); the padding is taken out again
_PREFIX_TIME, _PREFIX_TICK = 21, 11  # "%20.6f," and "%10d,"
_STATUS_NAMES = [s.name for s in E2EStatus]
_SIGNALS = (signal.SIGINT, signal.SIGTERM)  # held off while a chunk is written

Frame = tuple[int, bytes]


class _Tick:
    __slots__ = ("plant", "command", "ecu")

    def __init__(self) -> None:
        self.plant: list[Frame] | None = None
        self.command: list[Frame] = []
        self.ecu: list[Frame] | None = None


class _Group:
    """Frames of one message (or one multiplexer index) and the trace columns they set."""

    __slots__ = ("columns", "fields", "single")

    def __init__(self, columns: list[int], fields: list[tuple]) -> None:
        self.columns = np.array(columns, np.intp)
        self.fields = fields  # (start, mask, sign bit, scale, offset) per column
        self.single = True  # no other group writes these columns


class Recorder:
    def __init__(
        self,
        out_dir: Path,
        codec: Codec,
        period_s: float,
        *,
        commands: np.ndarray | None = None,
        channel: str = "vcan0",
        wall_clock: bool = False,
    ) -> None:
        self.codec = codec
        self.period_s = period_s
        self.commands = commands
        self.wall_clock = wall_clock
        self.log = CandumpWriter(out_dir / "can.log", channel)
        self.tick = 0  # ticks written (full count; the frames carry it modulo 2**16)
        self.bits = BitCounter()
        self.frames = 0
        self._unknown_ids: Counter[int] = Counter()
        self._sensor_ticks = TickTracker()
        self._actuator_ticks = TickTracker()
        self.latest_sensor_tick = -1  # full tick of the newest PlantSensors heard
        self._plant_pending: list[Frame] = []
        self._ecu_pending: list[Frame] = []
        self._ticks: dict[int, _Tick] = {}
        self._complete: set[int] = set()  # ticks whose plant and ECU frames are all in
        self._bad: set[bytes] = set()  # bytes of frames with a bad CRC, not yet logged
        self._bad_events: list[tuple[int, bytes]] = []  # (arrival, bytes): bad CRCs to replay
        self._sensor_wrap = TickUnwrapper()
        self._actuator_wrap = TickUnwrapper()

        # per frame ID: (length, E2E state or None); E2E state: [CRC start, last counter,
        # counts per status, message name]
        self._known: dict[int, tuple[int, list | None]] = {}
        self._e2e_seen: list[tuple[str, int]] = []  # (message, status) in order of first count
        for message in codec.messages:
            state = None
            if message.protected:
                state = [data_id_crc_start(message.data_id), -1, [0] * len(E2EStatus), message.name]
            self._known[message.frame_id] = (message.length, state)

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
        self._trace_file: TextIO = (out_dir / "trace.csv").open("w", newline="")
        header = ["time[s]", "tick[-]", "command[%N or V]", "speed_true[%]", "speed_meas[%]"]
        header += [f"{n}[{u or '-'}]" for n, u in zip(names, units, strict=True)]
        self._trace_file.write(",".join(header) + "\n")
        # one preformatted row, for rows the bulk path cannot lay out
        self._row_format = "%.6f,%d,%.9g,%.9g,%.9g," + ",".join(["%.9g"] * len(names)) + "\n"
        self.rows = 0
        self._commands_f = np.asarray(commands, np.float64) if commands is not None else np.zeros(0)

        # the chunk being gathered: frames heard (bit count), frames written in log order with
        # their timestamps as (base, count) blocks (frame i of a block at base + i * 10 us),
        # and rows as (tick, frames written before the row)
        self._heard_ids: list[int] = []
        self._heard_data: list[bytes] = []
        self._out_ids: list[int] = []
        self._out_data: list[bytes] = []
        self._out_base: list[float] = []
        self._out_count: list[int] = []
        self._out_heard: list[int] = []  # per block: frames heard when it was written
        self._out_done = 0  # frames written in earlier chunks
        self._row_ticks: list[int] = []
        self._row_pos: list[int] = []
        self._chunk_rows = min(CHUNK_ROWS, WALL_CLOCK_CHUNK_ROWS) if wall_clock else CHUNK_ROWS

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

    # -- frames in -------------------------------------------------------------------------------
    def record(self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None) -> None:
        """A frame heard on the bus, or sent by the command node (see the module docstring)."""
        data = bytes(data)
        self.frames += 1
        heard = self._heard_ids
        heard.append(frame_id)
        self._heard_data.append(data)
        if len(heard) >= _CHUNK_FRAMES:
            self._write_chunk()
        frame = (frame_id, data)
        if self.wall_clock:
            self._write(wall_s if wall_s is not None else 0.0, frame_id, data)
            if frame_id == ACTUATOR:
                self._end_row()
            return
        # (_flush_ready has nothing to do while no tick is complete)
        if frame_id in PLANT_IDS:
            self._plant_pending.append(frame)
            if frame_id == SENSORS:
                k = self._sensor_wrap.full(data[2] | data[3] << 8)
                if k > self.latest_sensor_tick:
                    self.latest_sensor_tick = k
                slot = self._ticks.get(k)
                if slot is None:
                    slot = self._ticks[k] = _Tick()
                slot.plant = self._plant_pending
                self._plant_pending = []
                if slot.ecu is not None:
                    self._complete.add(k)
            # a tick completed by its sensor frame waits for the command node's answers to that
            # frame, which belong to the tick (see commands_sent), or the next plant or ECU frame
            elif self._complete:
                self._flush_ready()
        elif frame_id in ECU_IDS:
            self._ecu_pending.append(frame)
            if frame_id == ACTUATOR:
                k = self._actuator_wrap.full(data[2] | data[3] << 8)
                slot = self._ticks.get(k)
                if slot is None:
                    slot = self._ticks[k] = _Tick()
                slot.ecu = self._ecu_pending
                self._ecu_pending = []
                if slot.plant is not None:
                    if k == self.tick and not self._complete:  # the usual case: this tick, now
                        del self._ticks[k]
                        self._write_tick(slot)
                        return
                    self._complete.add(k)
            if self._complete:
                self._flush_ready()
        elif self.latest_sensor_tick < 0:  # before tick 0: the first demands
            self._write(0.0, frame_id, data)
        else:  # the command node's frames (and foreign ones) go with the newest sensor tick
            # (no flush here: it may send several on one sensor frame, so a tick completed by its
            # sensor frame is written on the next plant or ECU frame, or at close)
            k = self.latest_sensor_tick
            slot = self._ticks.get(k)
            if slot is None:
                slot = self._ticks[k] = _Tick()
            slot.command.append(frame)

    @property
    def e2e(self) -> dict[str, Counter[str]]:
        """E2E verdicts per message name (only messages heard, only verdicts given)."""
        self._check_heard()
        out: dict[str, Counter[str]] = {}
        counts = {state[3]: state[2] for _, state in self._known.values() if state is not None}
        for name, status in self._e2e_seen:
            out.setdefault(name, Counter())[_STATUS_NAMES[status]] = counts[name][status]
        return out

    def commands_sent(self) -> None:
        """The command node has sent (and recorded) its frames on the latest sensor frame: a tick
        that sensor frame completed is written now. Waiting for the next plant or ECU frame
        instead would let the next tick's first frame in before the run's last tick ends it."""
        if self._complete:
            self._flush_ready()

    # -- ticks out -------------------------------------------------------------------------------
    def _flush_ready(self) -> None:
        ticks = self._ticks
        while True:
            tick = self.tick
            slot = ticks.get(tick)
            if slot is None or slot.plant is None or slot.ecu is None:
                # a tick with a lost frame is written once a later one is complete
                if not self._complete or max(self._complete) <= tick:
                    return
            slot = ticks.pop(tick, None)
            self._complete.discard(tick)
            self._write_tick(slot if slot is not None else _Tick())

    def _write_tick(self, slot: _Tick) -> None:
        ids, datas = self._out_ids, self._out_data
        first = len(ids)
        for frames in (slot.plant, slot.command, slot.ecu):
            if frames:  # (taken apart now, while they are in the cache)
                for frame_id, data in frames:
                    ids.append(frame_id)
                    datas.append(data)
        n = len(ids) - first
        if n:
            self._out_base.append(self.tick * self.period_s)
            self._out_count.append(n)
            self._out_heard.append(self.frames)
        if slot.ecu is not None:
            self._end_row()
        else:
            self.tick += 1

    def _write(self, timestamp_s: float, frame_id: int, data: bytes) -> None:
        self._out_ids.append(frame_id)
        self._out_data.append(data)
        self._out_base.append(timestamp_s)
        self._out_count.append(1)
        self._out_heard.append(self.frames)

    def _end_row(self) -> None:
        self._row_ticks.append(self.tick)
        self._row_pos.append(self._out_done + len(self._out_ids))
        self.rows += 1
        self.tick += 1
        if len(self._row_ticks) >= self._chunk_rows:
            self._write_chunk()

    @property
    def unknown_ids(self) -> Counter[int]:
        """Frames of IDs not in the contract, or of the wrong length, per ID."""
        self._check_heard()
        return self._unknown_ids

    @property
    def sensor_ticks(self) -> TickTracker:
        """SensorTick of every PlantSensors frame that passed its E2E check, in arrival order."""
        self._check_heard()
        return self._sensor_ticks

    @property
    def actuator_ticks(self) -> TickTracker:
        """ActuatorTick of every EcuActuator frame that passed its E2E check."""
        self._check_heard()
        return self._actuator_ticks

    @property
    def missed_ticks(self) -> int:
        """Ticks lost, repeated or out of order, as seen in the sensor and actuator streams."""
        return sum(
            t.missing + t.repeated + t.out_of_order
            for t in (self.sensor_ticks, self.actuator_ticks)
        )

    def totals(self) -> dict:
        """The run's figures: ticks written, frames heard, bits (all of them after close),
        ticks missed, E2E verdicts per message and frames of unknown IDs per ID."""
        return {
            "tick": self.tick,
            "frames": self.frames,
            "bits": self.bits.flush(),
            "missed_ticks": self.missed_ticks,
            "e2e": {m: dict(c) for m, c in self.e2e.items()},
            "unknown_ids": dict(self.unknown_ids),
        }

    def close(self) -> None:
        """Write whatever is still pending, in tick order, and close the files."""
        if self._trace_file.closed:
            return
        for k in sorted(self._ticks):
            if k >= self.tick:
                self.tick = k
                self._write_tick(self._ticks[k])
        self._ticks.clear()
        self._complete.clear()
        for frame_id, data in self._plant_pending + self._ecu_pending:
            self._write(self.tick * self.period_s, frame_id, data)
        self._plant_pending, self._ecu_pending = [], []
        self._write_chunk()
        self.log.close()
        if not self._trace_file.closed:
            self._trace_file.close()

    # -- bulk ------------------------------------------------------------------------------------
    def _check_heard(self) -> None:
        """E2E and tick-sequence checks and bit counts of the frames heard, in arrival order."""
        heard_ids, self._heard_ids = self._heard_ids, []
        heard, self._heard_data = self._heard_data, []
        if not heard:
            return
        first = self.frames - len(heard)  # arrival number of heard[0]
        ids, payload, lengths = self._frames_array(heard_ids, heard)
        if (lengths == 8).all():
            self.bits.add_many(ids, payload, lengths)
        else:
            for frame_id, data in zip(heard_ids, heard, strict=True):
                self.bits.add(frame_id, data)
        good = np.zeros(len(ids), bool)  # known ID, right length, E2E not WRONGCRC
        for frame_id, (length, _) in self._known.items():
            good |= (ids == frame_id) & (lengths == length)
        if not good.all():
            for frame_id in ids[~good].tolist():
                self._unknown_ids[frame_id] += 1
        seen: list[tuple[int, str, int]] = []
        bad: list[int] = []
        for frame_id, (length, state) in self._known.items():
            if state is None:
                continue
            rows = np.flatnonzero(good & (ids == frame_id))
            if not len(rows):
                continue
            p = payload[rows]
            counter = (p[:, 1] & 0x0F).astype(np.int64)
            valid = (crc8_rows(p[:, 1:length], state[0]) == p[:, 0]) & (counter < COUNTER_MODULO)
            if length < 2:
                valid[:] = False
            status = np.full(len(rows), int(E2EStatus.WRONGCRC), np.int64)
            accepted = counter[valid]
            if len(accepted):
                # as E2EChecker.check with max_delta=14: any change of the counter is OK
                previous = np.concatenate(([state[1]], accepted[:-1]))
                status[valid] = np.where(
                    (previous >= 0) & (accepted == previous), int(E2EStatus.REPEATED), 0
                )
                state[1] = int(accepted[-1])
            counts = state[2]
            for s, c in enumerate(np.bincount(status, minlength=len(counts)).tolist()):
                if c:
                    if not counts[s]:
                        seen.append((int(rows[np.argmax(status == s)]), state[3], s))
                    counts[s] += c
            if not valid.all():
                invalid = rows[~valid]
                good[invalid] = False
                bad += invalid.tolist()
        seen.sort()
        self._e2e_seen += [(name, s) for _, name, s in seen]
        for i in sorted(bad):  # logged, never decoded into the trace
            self._bad_events.append((first + i, heard[i]))
        for frame_id, tracker in ((SENSORS, self._sensor_ticks), (ACTUATOR, self._actuator_ticks)):
            rows = np.flatnonzero(good & (ids == frame_id))
            if len(rows):
                ticks = payload[rows, 2].astype(np.int64) | payload[rows, 3].astype(np.int64) << 8
                last = tracker.last
                if (np.diff(ticks) % TICK_MODULO == 1).all() and (
                    last < 0 or (int(ticks[0]) - last) % TICK_MODULO == 1
                ):
                    tracker.last = int(ticks[-1])  # every tick the next: nothing to count
                else:
                    for tick in ticks.tolist():
                        tracker.observe(tick)

    def _not_decoded(
        self, frame_ids: list[int], datas: list[bytes], count: list[int], heard: list[int]
    ) -> list[int]:
        """Frames logged with a bad CRC (by index in the chunk): never decoded into the trace.

        Replays, in the order they happened, a bad frame heard (its bytes go into the bad set)
        and a frame logged (bytes found in the set are taken out, and the frame not decoded).
        """
        events, self._bad_events = self._bad_events, []
        bad = self._bad
        out: list[int] = []
        e = 0
        i = 0
        for n, heard_then in zip(count, heard, strict=True):
            while e < len(events) and events[e][0] < heard_then:
                bad.add(events[e][1])
                e += 1
            if bad:
                for j in range(i, i + n):
                    data = datas[j]
                    known = self._known.get(frame_ids[j])
                    if known is not None and len(data) == known[0] and data in bad:
                        bad.discard(data)
                        out.append(j)
            i += n
        self._bad_events = events[e:]
        return out

    @staticmethod
    def _frames_array(
        ids: list[int], datas: list[bytes]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(datas)
        blob = b"".join(datas)
        if len(blob) == 8 * n and max(map(len, datas)) == 8:
            payload = np.frombuffer(blob, np.uint8).reshape(n, 8)
            lengths = np.full(n, 8, np.int64)
        else:
            payload = np.zeros((n, 8), np.uint8)
            lengths = np.array([len(d) for d in datas], np.int64)
            for i, d in enumerate(datas):
                payload[i, : min(len(d), 8)] = np.frombuffer(d[:8], np.uint8)
        return np.array(ids, np.int64), payload, lengths

    def _write_chunk(self) -> None:
        """Write the gathered frames to can.log and rows to trace.csv, decoded in bulk.

        Ctrl-C and SIGTERM wait until the chunk is written (a few milliseconds): an interrupted
        chunk would leave a gap in the files that close() could not fill.
        """
        if threading.current_thread() is not threading.main_thread():
            self._write_chunk_now()  # signals are handled in the main thread only
            return
        held: list[int] = []
        previous = {}
        for signum in _SIGNALS:
            handler = signal.getsignal(signum)
            if handler is not None:  # (None: a handler not installed from Python; left alone)
                previous[signum] = signal.signal(signum, lambda n, _f: held.append(n))
        try:
            self._write_chunk_now()
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            for signum in held:
                signal.raise_signal(signum)  # now, to the handler it was meant for

    def _write_chunk_now(self) -> None:
        self._check_heard()
        frame_ids, self._out_ids = self._out_ids, []
        datas, self._out_data = self._out_data, []
        base, self._out_base = self._out_base, []
        count, self._out_count = self._out_count, []
        heard, self._out_heard = self._out_heard, []
        row_ticks, self._row_ticks = self._row_ticks, []
        row_pos, self._row_pos = self._row_pos, []
        done = self._out_done
        n = len(datas)
        self._out_done += n
        if n:
            ids, payload, lengths = self._frames_array(frame_ids, datas)
            if lengths.max() > 8:  # not classical CAN: one by one
                ts = self._timestamps(base, count)
                for frame_id, data, t in zip(frame_ids, datas, ts.tolist(), strict=True):
                    self.log.write(t, frame_id, data)
            else:
                self.log.write_many(self._timestamps(base, count), ids, payload, lengths)
        else:
            ids = np.zeros(0, np.int64)
            payload = np.zeros((0, 8), np.uint8)
            lengths = np.zeros(0, np.int64)
        no_decode = (
            self._not_decoded(frame_ids, datas, count, heard)
            if self._bad or self._bad_events
            else []
        )
        self._write_rows(ids, payload, lengths, no_decode, row_ticks, row_pos, done)
        self.log.flush()
        self._trace_file.flush()

    @staticmethod
    def _timestamps(base: list[float], count: list[int]) -> np.ndarray:
        counts = np.array(count, np.int64)
        starts = np.cumsum(counts) - counts
        seq = np.arange(int(counts.sum())) - np.repeat(starts, counts)
        return np.repeat(np.array(base, np.float64), counts) + seq * _FRAME_SPACING_S

    def _write_rows(
        self,
        ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
        no_decode: list[int],
        row_ticks: list[int],
        row_pos: list[int],
        done: int,
    ) -> None:
        n = len(ids)
        ncols = len(self._carry)
        # rows plus one at the chunk's end (the values carried into the next chunk)
        pos = np.array([*row_pos, done + n], np.int64) - done
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
            for frame_id, (length, _) in self._known.items():
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
        ticks = np.array(row_ticks, np.int64)
        c = self._columns
        true = values[cell[:, c["TrueSpeed"]]]
        meas = values[cell[:, c["ShaftSpeed"]]]
        commands = self._commands_f
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
        self._trace_file.write(self._format_rows(ticks, values, cell))

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


def _decode(words: np.ndarray, fields: list[tuple]) -> np.ndarray:
    """Physical values (frames, signals) of 64-bit little-endian frame words."""
    out = np.empty((len(words), len(fields)), np.float64)
    for j, (start, mask, sign_bit, scale, offset) in enumerate(fields):
        raw = ((words >> np.uint64(start)) & np.uint64(mask)).astype(np.int64)
        if sign_bit:
            raw = np.where(raw & sign_bit, raw - (sign_bit << 1), raw)
        out[:, j] = raw.astype(np.float64) * scale + offset
    return out


class TickUnwrapper:
    """Full tick numbers from the 16-bit ones on the bus (ticks only move forward, mostly)."""

    __slots__ = ("last",)

    def __init__(self) -> None:
        self.last = -1

    def full(self, tick16: int) -> int:
        if self.last < 0:
            self.last = tick16
            return tick16
        delta = (tick16 - self.last) % TICK_MODULO
        if delta >= TICK_MODULO // 2:
            delta -= TICK_MODULO
        self.last += delta
        return self.last


class InOrderTicks:
    """The ticks as the command node reads them from a recorder that sees every frame, none
    lost: the newest sensor tick, and one tick answered per EcuActuator. The base of the
    stand-ins for the :class:`Recorder` (the campaign's probe, the recorder process's feed)."""

    def __init__(self) -> None:
        self.tick = 0  # ticks answered
        self.latest_sensor_tick = -1
        self._sensor_wrap = TickUnwrapper()

    def track(self, frame_id: int, data: bytes | bytearray) -> None:
        if frame_id == SENSORS:
            k = self._sensor_wrap.full(data[2] | data[3] << 8)
            if k > self.latest_sensor_tick:
                self.latest_sensor_tick = k
        elif frame_id == ACTUATOR:
            self.tick += 1
