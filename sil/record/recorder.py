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
unknown IDs (:mod:`sil.record.frame_checks`) and bit counts in arrival order; the can.log lines as a
character matrix (:mod:`sil.record.canlog`); the signals decoded by shifts and masks per message,
the trace cells sample-and-hold by position, each distinct value %-formatted once
(:mod:`sil.record.trace_writer`). ``e2e``, ``unknown_ids`` and the tick trackers check the frames
still pending when read; ``bits`` is complete after close.

Frames that come already in the canonical order, whole ticks at a time as numpy arrays (a loop
that runs the nodes itself), skip the per-frame work: ``record_ticks`` checks the block's order
and ticks (:func:`sil.record.ticks.tick_block`), E2E and bits vectorised, and places the block in
the chunk as arrays; the files and figures are those of the same frames recorded one by one, byte
for byte.
"""

from __future__ import annotations

import signal
import threading
from collections import Counter
from pathlib import Path

import numpy as np

from protocol.busload import BitCounter
from protocol.codec import Codec
from protocol.lockstep import TickTracker
from sil.record.canlog import CandumpWriter
from sil.record.frame_checks import FrameChecks
from sil.record.results import named
from sil.record.ticks import ACTUATOR, ECU_IDS, PLANT_IDS, SENSORS, TickUnwrapper, tick_block
from sil.record.trace_writer import TraceWriter

_FRAME_SPACING_S = 10e-6
CHUNK_ROWS = 2048  # trace rows (ticks) per bulk write (20 s simulated at 100 Hz)
WALL_CLOCK_CHUNK_ROWS = 100  # in real time: on disk at least every 100 ECU periods
_CHUNK_FRAMES = 32768  # frames heard per bulk write when no rows come
_SIGNALS = (signal.SIGINT, signal.SIGTERM)  # held off while a chunk is written

Frame = tuple[int, bytes]


class _Tick:
    __slots__ = ("plant", "command", "ecu")

    def __init__(self) -> None:
        self.plant: list[Frame] | None = None
        self.command: list[Frame] = []
        self.ecu: list[Frame] | None = None


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
        with named(out_dir / "can.log"):
            self.log = CandumpWriter(out_dir / "can.log", channel)
        self.tick = 0  # ticks written (full count; the frames carry it modulo 2**16)
        self.bits = BitCounter()
        self.frames = 0
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
        self._checks = FrameChecks(codec)
        with named(out_dir / "trace.csv"):
            self.trace = TraceWriter(out_dir / "trace.csv", codec, period_s, commands)
        self.rows = 0

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
        return self._checks.e2e

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
        if self.trace.closed:
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
        return self._checks.unknown_ids

    @property
    def wrong_length(self) -> Counter[int]:
        """Frames of IDs in the contract but of another length, per ID."""
        self._check_heard()
        return self._checks.wrong_length

    @property
    def sensor_ticks(self) -> TickTracker:
        """SensorTick of every PlantSensors frame that passed its E2E check, in arrival order."""
        self._check_heard()
        return self._checks.sensor_ticks

    @property
    def actuator_ticks(self) -> TickTracker:
        """ActuatorTick of every EcuActuator frame that passed its E2E check."""
        self._check_heard()
        return self._checks.actuator_ticks

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
        if self.trace.closed:
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
        try:
            self._write_chunk()
        finally:
            try:
                with named(self.log.path):
                    self.log.close()
            finally:
                with named(self.trace.path):
                    self.trace.close()

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
            for i in self._checks.check(ids, payload, lengths).tolist():  # logged, not decoded
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
        for i in self._checks.check(ids, payload, lengths).tolist():  # logged, never decoded
            self._bad_events.append((first + i, heard[i]))

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
                    known = self._checks.known.get(int(ids[j]))
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
        with named(self.log.path):
            self._log_chunk(segments, ids, payload, lengths, times)
        no_decode: list[int] = []
        if self._bad or self._bad_events:
            offsets = np.cumsum([0] + [len(s.ids) for s in segments[:-1]])
            starts = np.concatenate([s.starts + o for s, o in zip(segments, offsets, strict=True)])
            heard = np.concatenate([s.heard for s in segments])
            no_decode = self._not_decoded(ids, payload, lengths, starts, heard)
        with named(self.trace.path):
            self.trace.write_rows(ids, payload, lengths, no_decode, row_ticks, row_pos, done)
            self.trace.flush()

    def _log_chunk(
        self,
        segments: list[_Segment],
        ids: np.ndarray,
        payload: np.ndarray,
        lengths: np.ndarray,
        times: np.ndarray,
    ) -> None:
        """A chunk's frames into can.log."""
        if len(ids):
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
        self.log.flush()

    @staticmethod
    def _timestamps(base: list[float] | np.ndarray, count: list[int] | np.ndarray) -> np.ndarray:
        """Frame i of a block at its base + i * 10 us."""
        counts = np.asarray(count, np.int64)
        starts = np.cumsum(counts) - counts
        seq = np.arange(int(counts.sum())) - np.repeat(starts, counts)
        return np.repeat(np.asarray(base, np.float64), counts) + seq * _FRAME_SPACING_S
