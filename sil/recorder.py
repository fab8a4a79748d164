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

Frames that come already in the canonical order, whole ticks at a time as numpy arrays (a loop
that runs the nodes itself), skip the per-frame work: ``record_ticks`` checks the block's order
and ticks, E2E and bits vectorised, and places the block in the chunk as arrays; the files and
figures are those of the same frames recorded one by one, byte for byte.
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


class _Segment:
    """Frames placed in the log order, as arrays: in blocks (a tick, or a frame written alone)
    whose frames are stamped from one base; per block its first frame and the frames heard when
    it was written (what _not_decoded replays); and the trace rows ended among them."""

    __slots__ = (
        "ids",
        "payload",
        "lengths",
        "times",
        "starts",
        "heard",
        "datas",
        "row_ticks",
        "row_pos",
    )

    def __init__(
        self,
        ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
        times: np.ndarray,
        starts: np.ndarray,
        heard: np.ndarray,
        datas: list[bytes] | None,
        row_ticks: np.ndarray,
        row_pos: np.ndarray,
    ) -> None:
        self.ids = ids  # int64
        self.payload = payload  # (frames, 8) uint8, zero beyond each frame's length
        self.lengths = lengths  # int64
        self.times = times  # float64: the log's timestamps
        self.starts = starts  # int64, per block
        self.heard = heard  # int64, per block
        self.datas = datas  # the frames' bytes (frames recorded one by one), or None
        self.row_ticks = row_ticks  # int64: the tick of each row
        self.row_pos = row_pos  # int64: frames placed before each row (from the run's start)


# the frame classes in a tick, in their canonical order (record_ticks)
_PLANT, _SENSORS, _OTHER, _ECU, _ACTUATOR = range(5)
_CLASS = np.full(0x800, _OTHER, np.int8)
_CLASS[[i for i in PLANT_IDS if i != SENSORS]] = _PLANT
_CLASS[SENSORS] = _SENSORS
_CLASS[[i for i in ECU_IDS if i != ACTUATOR]] = _ECU
_CLASS[ACTUATOR] = _ACTUATOR


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
        self._wrong_length: Counter[int] = Counter()
        self._sensor_ticks = TickTracker()
        self._actuator_ticks = TickTracker()
        self.latest_sensor_tick = -1  # full tick of the newest PlantSensors heard
        self._plant_pending: list[Frame] = []
        self._ecu_pending: list[Frame] = []
        self._ticks: dict[int, _Tick] = {}
        self._complete: set[int] = set()  # ticks whose plant and ECU frames are all in
        self._bad: set[bytes] = set()  # bytes of frames with a bad CRC, not yet logged
        self._bad_events: list[tuple[int, bytes]] = []  # (arrival, bytes): bad CRCs to replay
        # blocks of ticks heard (IDs, payload), not yet checked: all before the frames heard in
        # the lists below; the arrival number of their first frame
        self._heard_blocks: list[tuple[np.ndarray, np.ndarray]] = []
        self._blocks_first = 0
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
        # the same per 11-bit ID, for lookups in bulk: the message's length, -1 for no message
        self._length_of = np.full(0x800, -1, np.int64)
        for frame_id, (length, _) in self._known.items():
            if 0 <= frame_id < 0x800:
                self._length_of[frame_id] = length

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
        self._out_done = 0  # frames placed in the log order before those in the lists above
        self._row_ticks: list[int] = []
        self._row_pos: list[int] = []
        # ... and what was gathered before those lists, as arrays (see _seal and record_ticks)
        self._segments: list[_Segment] = []
        self._sealed_rows = 0  # rows in the segments
        self._chunk_done = 0  # frames written in earlier chunks
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

    def record_ticks(self, frame_ids: np.ndarray, payload: np.ndarray) -> None:
        """Whole ticks at once, their frames in the canonical order (see :func:`tick_block`):
        the files, the figures and the state end up as if every frame had been recorded one by
        one, with commands_sent() after the command node's frames on each PlantSensors, as the
        command node does. The frames are checked and placed vectorised over the block, whose
        first tick must be the next to be written (:attr:`tick`): frames recorded one by one
        before it must make whole ticks (a block follows an EcuActuator). The arrays are copied.

        Raises ValueError (nothing recorded) if the block is not such whole ticks.
        """
        if self.wall_clock:
            raise ValueError("record_ticks: not in real time (its frames are written as they come)")
        if self._trace_file.closed:
            raise ValueError("record_ticks: the recorder is closed")
        if self._ticks or self._plant_pending or self._ecu_pending:
            pending = len(self._plant_pending) + len(self._ecu_pending)
            for slot in self._ticks.values():
                pending += len(slot.plant or ()) + len(slot.command) + len(slot.ecu or ())
            raise ValueError(
                f"record_ticks: {pending} frame(s) recorded one by one not yet written as whole"
                f" ticks (ticks {sorted(self._ticks)} begun, the next to write {self.tick}):"
                " a block must follow an EcuActuator"
            )
        ids, ends = tick_block(
            frame_ids, payload, self.tick, self._sensor_wrap.last, self._actuator_wrap.last
        )
        if not len(ids):
            return
        payload = np.array(payload, np.uint8)  # (a copy: the caller may reuse its arrays)
        lengths = np.full(len(ids), 8, np.int64)
        if self._heard_ids:
            self._check_heard()  # the frames heard one by one before the block: checked first
        self._seal()  # and logged first
        # in pieces that end where a chunk ends, each recorded whole before its chunk is written
        # (a Ctrl-C held while it is written then leaves the recorder as after a tick)
        done = 0
        while done < len(ends):
            room = self._chunk_rows - self._sealed_rows - len(self._row_ticks)
            take = min(len(ends) - done, max(room, 1))
            lo = int(ends[done - 1]) if done else 0
            piece = ends[done : done + take] - lo
            hi = lo + int(piece[-1])
            self._place_ticks(ids[lo:hi], payload[lo:hi], lengths[lo:hi], piece)
            done += take

    def _place_ticks(
        self, ids: np.ndarray, payload: np.ndarray, lengths: np.ndarray, ends: np.ndarray
    ) -> None:
        """Whole ticks from :attr:`tick` on (checked by tick_block), tick i ending before
        frame ``ends[i]``: heard (E2E, ticks and bits are checked with the chunk, or when asked,
        by _check_heard), placed in the log and ended in rows."""
        first = self.frames  # arrival number of the first frame
        n = len(ids)
        self.frames += n
        if not self._heard_blocks:
            self._blocks_first = first
        self._heard_blocks.append((ids, payload))  # checked with the chunk, or when asked
        count = len(ends)
        ticks = np.arange(self.tick, self.tick + count)
        starts = np.concatenate(([0], ends[:-1]))
        self._segments.append(
            _Segment(
                ids,
                payload,
                lengths,
                self._timestamps(ticks * self.period_s, ends - starts),
                starts,
                first + ends,  # each tick written as its EcuActuator is heard
                None,
                ticks,
                self._out_done + ends,
            )
        )
        self._out_done += n
        self._sealed_rows += count
        self.rows += count
        self.tick += count
        last = self.tick - 1  # the full tick of the last PlantSensors and EcuActuator
        self._sensor_wrap.last = self._actuator_wrap.last = last
        if last > self.latest_sensor_tick:
            self.latest_sensor_tick = last
        if self._sealed_rows >= self._chunk_rows:
            self._write_chunk()

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
        if len(self._row_ticks) + self._sealed_rows >= self._chunk_rows:
            self._write_chunk()

    @property
    def unknown_ids(self) -> Counter[int]:
        """Frames of IDs not in the contract, per ID."""
        self._check_heard()
        return self._unknown_ids

    @property
    def wrong_length(self) -> Counter[int]:
        """Frames of IDs in the contract but of another length, per ID."""
        self._check_heard()
        return self._wrong_length

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
        ticks missed, E2E verdicts per message, frames of unknown IDs and of the wrong length
        per ID."""
        return {
            "tick": self.tick,
            "frames": self.frames,
            "bits": self.bits.flush(),
            "missed_ticks": self.missed_ticks,
            "e2e": {m: dict(c) for m, c in self.e2e.items()},
            "unknown_ids": dict(self.unknown_ids),
            "wrong_length": dict(self.wrong_length),
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
        if self._heard_blocks:  # (heard before the frames in the lists)
            blocks, self._heard_blocks = self._heard_blocks, []
            ids = np.concatenate([b[0] for b in blocks]) if len(blocks) > 1 else blocks[0][0]
            payload = np.concatenate([b[1] for b in blocks]) if len(blocks) > 1 else blocks[0][1]
            lengths = np.full(len(ids), 8, np.int64)
            self.bits.add_many(ids, payload, lengths)
            first = self._blocks_first
            for i in self._check_frames(ids, payload, lengths).tolist():  # logged, not decoded
                self._bad_events.append((first + i, payload[i].tobytes()))
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
        for i in self._check_frames(ids, payload, lengths).tolist():  # logged, never decoded
            self._bad_events.append((first + i, heard[i]))

    def _check_frames(
        self, ids: np.ndarray, payload: np.ndarray, lengths: np.ndarray
    ) -> np.ndarray:
        """E2E and tick-sequence checks of frames heard one after the other (after those checked
        before), unknown IDs and wrong lengths counted; returns the indices of the frames with a
        bad CRC."""
        inside = (ids >= 0) & (ids < 0x800)
        if inside.all():  # known ID, right length, E2E not WRONGCRC
            good = self._length_of[ids] == lengths
        else:
            good = np.zeros(len(ids), bool)
            good[inside] = self._length_of[ids[inside]] == lengths[inside]
            for frame_id, (length, _) in self._known.items():
                if not 0 <= frame_id < 0x800:
                    good |= (ids == frame_id) & (lengths == length)
        if not good.all():
            for frame_id in ids[~good].tolist():
                known = frame_id in self._known
                (self._wrong_length if known else self._unknown_ids)[frame_id] += 1
        present = set(np.unique(ids[good]).tolist())
        seen: list[tuple[int, str, int]] = []
        bad: list[np.ndarray] = []
        for frame_id, (length, state) in self._known.items():
            if state is None or frame_id not in present:
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
                bad.append(invalid)
        seen.sort()
        self._e2e_seen += [(name, s) for _, name, s in seen]
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
        return np.sort(np.concatenate(bad)) if bad else np.zeros(0, np.intp)

    def _not_decoded(
        self,
        ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
        starts: np.ndarray,
        heard: np.ndarray,
    ) -> list[int]:
        """Frames logged with a bad CRC (by index in the chunk): never decoded into the trace.

        Replays, in the order they happened, a bad frame heard (its bytes go into the bad set)
        and a frame logged (bytes found in the set are taken out, and the frame not decoded).
        The frames were logged in blocks beginning at ``starts``, each when ``heard`` frames had
        been heard; blocks logged while the set is empty and no bad frame comes are skipped.
        """
        events, self._bad_events = self._bad_events, []
        bad = self._bad
        out: list[int] = []
        e = 0
        b = 0
        blocks = len(starts)
        ends = np.append(starts[1:], len(ids)).tolist()
        starts_l, heard_l = starts.tolist(), heard.tolist()
        while b < blocks:
            if not bad:
                if e == len(events):
                    break
                b = max(b, int(np.searchsorted(heard, events[e][0], "right")))
                if b == blocks:
                    break
            heard_then = heard_l[b]
            while e < len(events) and events[e][0] < heard_then:
                bad.add(events[e][1])
                e += 1
            if bad:
                for j in range(starts_l[b], ends[b]):
                    known = self._known.get(int(ids[j]))
                    length = int(lengths[j])
                    if known is not None and length == known[0]:
                        data = payload[j, :length].tobytes()
                        if data in bad:
                            bad.discard(data)
                            out.append(j)
            b += 1
        self._bad_events = events[e:]
        return out

    @staticmethod
    def _frames_array(
        ids: list[int], datas: list[bytes]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(datas)
        blob = b"".join(datas)
        if len(blob) == 8 * n and (not n or max(map(len, datas)) == 8):
            payload = np.frombuffer(blob, np.uint8).reshape(n, 8)
            lengths = np.full(n, 8, np.int64)
        else:
            payload = np.zeros((n, 8), np.uint8)
            lengths = np.array([len(d) for d in datas], np.int64)
            for i, d in enumerate(datas):
                payload[i, : min(len(d), 8)] = np.frombuffer(d[:8], np.uint8)
        return np.array(ids, np.int64), payload, lengths

    def _seal(self) -> None:
        """The frames and rows gathered one by one into a segment: before a block of ticks is
        placed after them, and when the chunk is written."""
        datas = self._out_data
        if not datas and not self._row_ticks:
            return
        ids, payload, lengths = self._frames_array(self._out_ids, datas)
        counts = np.array(self._out_count, np.int64)
        segment = _Segment(
            ids,
            payload,
            lengths,
            self._timestamps(self._out_base, counts),
            np.cumsum(counts) - counts,
            np.array(self._out_heard, np.int64),
            datas,
            np.array(self._row_ticks, np.int64),
            np.array(self._row_pos, np.int64),
        )
        self._segments.append(segment)
        self._out_done += len(datas)
        self._sealed_rows += len(self._row_ticks)
        self._out_ids, self._out_data, self._out_base = [], [], []
        self._out_count, self._out_heard = [], []
        self._row_ticks, self._row_pos = [], []

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
        self._seal()
        segments, self._segments = self._segments, []
        self._sealed_rows = 0
        done = self._chunk_done  # frames written in earlier chunks
        self._chunk_done = self._out_done
        if not segments:
            return
        if len(segments) == 1:
            (s,) = segments
            ids, payload, lengths, times = s.ids, s.payload, s.lengths, s.times
            row_ticks, row_pos = s.row_ticks, s.row_pos
        else:
            ids = np.concatenate([s.ids for s in segments])
            payload = np.concatenate([s.payload for s in segments])
            lengths = np.concatenate([s.lengths for s in segments])
            times = np.concatenate([s.times for s in segments])
            row_ticks = np.concatenate([s.row_ticks for s in segments])
            row_pos = np.concatenate([s.row_pos for s in segments])
        n = len(ids)
        if n:
            if lengths.max() > 8:  # not classical CAN: one by one
                datas = [
                    d
                    for s in segments
                    for d in (s.datas if s.datas is not None else [r.tobytes() for r in s.payload])
                ]
                for frame_id, data, t in zip(ids.tolist(), datas, times.tolist(), strict=True):
                    self.log.write(t, frame_id, data)
            else:
                self.log.write_many(times, ids, payload, lengths)
        no_decode: list[int] = []
        if self._bad or self._bad_events:
            offsets = np.cumsum([0] + [len(s.ids) for s in segments[:-1]])
            starts = np.concatenate([s.starts + o for s, o in zip(segments, offsets, strict=True)])
            heard = np.concatenate([s.heard for s in segments])
            no_decode = self._not_decoded(ids, payload, lengths, starts, heard)
        self._write_rows(ids, payload, lengths, no_decode, row_ticks, row_pos, done)
        self.log.flush()
        self._trace_file.flush()

    @staticmethod
    def _timestamps(base: list[float] | np.ndarray, count: list[int] | np.ndarray) -> np.ndarray:
        """Frame i of a block at its base + i * 10 us."""
        counts = np.asarray(count, np.int64)
        starts = np.cumsum(counts) - counts
        seq = np.arange(int(counts.sum())) - np.repeat(starts, counts)
        return np.repeat(np.asarray(base, np.float64), counts) + seq * _FRAME_SPACING_S

    def _write_rows(
        self,
        ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
        no_decode: list[int],
        row_ticks: np.ndarray,
        row_pos: np.ndarray,
        done: int,
    ) -> None:
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
        ticks = np.asarray(row_ticks, np.int64)
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


def tick_block(
    frame_ids: np.ndarray,
    payload: np.ndarray,
    first_tick: int,
    sensor_last: int = -1,
    actuator_last: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Checks that a block of frames is whole ticks in their canonical order, from ``first_tick``
    on: each tick the plant's frames (PlantTruthA/B, PlantAnalog), PlantSensors(k), the command
    node's frames (and any foreign ones), the ECU's (EcuStatus, EcuTelemetry), EcuActuator(k);
    all of them 8-byte frames with 11-bit IDs, ``payload`` (frames, 8) uint8. The ticks are read
    as the recorder reads them: unwrapped from ``sensor_last`` and ``actuator_last`` (the last
    full ticks, -1 if none yet; None: the 16-bit ticks only). Vectorised; what went wrong is
    worked out only when something did.

    Returns the IDs (int64) and where each tick ends (the index after its EcuActuator); raises
    ValueError naming the first frame that is wrong.
    """
    ids = np.asarray(frame_ids)
    if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
        raise ValueError(
            f"record_ticks: frame_ids is not a 1-D integer array ({ids.dtype}, shape {ids.shape})"
        )
    data = np.asarray(payload)
    if data.dtype != np.uint8 or data.shape != (len(ids), 8):
        raise ValueError(
            f"record_ticks: payload is not a ({len(ids)}, 8) uint8 array of 8-byte frames"
            f" ({data.dtype}, shape {data.shape})"
        )
    ids = ids.astype(np.int64)
    if not len(ids):
        return ids, np.zeros(0, np.int64)
    if ids.min() < 0 or ids.max() > 0x7FF:
        i = int(np.flatnonzero((ids < 0) | (ids > 0x7FF))[0])
        raise ValueError(f"record_ticks: frame {i} of the block: ID {int(ids[i])} is not 11-bit")
    cls = _CLASS[ids]
    if cls[-1] != _ACTUATOR:
        raise ValueError("record_ticks: the block does not end with an EcuActuator (whole ticks)")
    ends = np.flatnonzero(cls == _ACTUATOR) + 1
    # within a tick the classes go up: nothing comes back after the next class has begun
    down = cls[1:] < cls[:-1]
    if down.any():
        wrong = np.flatnonzero(down & (cls[:-1] != _ACTUATOR))
        if len(wrong):
            i = int(wrong[0]) + 1
            raise ValueError(
                f"record_ticks: frame {i} of the block: ID {int(ids[i]):#05x} after"
                f" {int(ids[i - 1]):#05x} in a tick, not in the order of a tick (the plant's"
                " frames, PlantSensors, the command node's frames, the ECU's frames, EcuActuator)"
            )
    sensors = np.flatnonzero(cls == _SENSORS)
    # one PlantSensors in each tick: the k-th after tick k - 1 ends and before tick k ends
    if len(sensors) != len(ends) or (sensors >= ends).any() or (sensors[1:] < ends[:-1]).any():
        per_tick = np.diff(np.searchsorted(sensors, ends), prepend=0)
        t = int(np.flatnonzero(per_tick != 1)[0])
        start = int(ends[t - 1]) if t else 0
        raise ValueError(
            f"record_ticks: frames {start}..{int(ends[t]) - 1} of the block (tick"
            f" {first_tick + t}): {int(per_tick[t])} PlantSensors, expected one"
        )
    # the ticks one after the other, from first_tick on: the 16-bit numbers, and the first as
    # the recorder unwraps it (the others then each one more)
    expected = np.arange(first_tick, first_tick + len(ends)) % TICK_MODULO
    for name, rows, last in (
        ("PlantSensors", sensors, sensor_last),
        ("EcuActuator", ends - 1, actuator_last),
    ):
        tick16 = data[rows, 2] | data[rows, 3].astype(np.int64) << 8
        wrong = tick16 != expected
        if wrong.any():
            j = int(np.argmax(wrong))
            raise ValueError(
                f"record_ticks: frame {int(rows[j])} of the block: {name} tick {int(tick16[j])},"
                f" expected {int(expected[j])}"
            )
        if last is not None and (full := _unwrap_one(last, int(tick16[0]))) != first_tick:
            raise ValueError(
                f"record_ticks: frame {int(rows[0])} of the block: {name} tick"
                f" {int(tick16[0])} reads as {full} after {last}, expected {first_tick}"
            )
    return ids, ends


def _unwrap_one(last: int, tick16: int) -> int:
    """:meth:`TickUnwrapper.full` of one 16-bit tick after the full tick ``last`` (-1: none)."""
    if last < 0:
        return tick16
    delta = (tick16 - last) % TICK_MODULO
    return last + (delta - TICK_MODULO if delta >= TICK_MODULO // 2 else delta)


def _unwrap(last: int, tick16: np.ndarray) -> np.ndarray:
    """:meth:`TickUnwrapper.full` of each 16-bit tick in turn, from ``last`` on (vectorised)."""
    if not len(tick16):
        return tick16
    base = int(tick16[0]) if last < 0 else last
    delta = np.diff(tick16, prepend=base) % TICK_MODULO
    delta = np.where(delta >= TICK_MODULO // 2, delta - TICK_MODULO, delta)
    return base + np.cumsum(delta)


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

    def track_many(self, frame_ids: np.ndarray, payload: np.ndarray) -> None:
        """:meth:`track` of every frame of a block, vectorised: ``payload`` (frames, 8) uint8."""
        ids = np.asarray(frame_ids)
        self.tick += int(np.count_nonzero(ids == ACTUATOR))
        rows = np.flatnonzero(ids == SENSORS)
        if len(rows):
            data = np.asarray(payload)
            tick16 = data[rows, 2].astype(np.int64) | data[rows, 3].astype(np.int64) << 8
            full = _unwrap(self._sensor_wrap.last, tick16)
            self._sensor_wrap.last = int(full[-1])
            self.latest_sensor_tick = max(self.latest_sensor_tick, int(full.max()))
