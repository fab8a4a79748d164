"""The recorder: every frame into ``can.log``, every signal per tick into ``trace.csv``.

It hears the whole bus (or is handed the frames in-process), checks E2E on every protected
message as frames arrive, counts bits for the bus load, and keeps, sample-and-hold, the latest
value of every DBC signal; the trace gets one row per tick.

In lockstep, frames from different senders may reach the recorder in either order (the kernel
delivers one multicast frame to each listener in turn, and a fast ECU can answer before the
recorder has read the frame it answers). Each sender's own frames keep their order, so the
recorder sorts every frame into its tick: the plant's frames up to and including PlantSensors(k),
the command node's frames sent on PlantSensors(k), then the ECU's frames up to and including
EcuActuator(k). A tick is written once both ends are in, in that canonical order, stamped with
simulated time (the tick's start plus 10 us per frame). The log is therefore the same however
the frames interleaved. In real time the frames are written as they come, with wall-clock stamps.
Everything is flushed as it goes, and whatever is pending is written at close, so an aborted run
keeps what it recorded.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import TextIO

import numpy as np

from protocol.busload import BitCounter
from protocol.codec import Codec
from protocol.e2e import E2EChecker, E2EStatus
from protocol.lockstep import TICK_MODULO, TickTracker
from sil.canlog import CandumpWriter

N_MAX_RPM = 112_500.0
_FRAME_SPACING_S = 10e-6
_SKIP = ("_CRC", "_Counter")
SENSORS, ACTUATOR = 0x100, 0x110
PLANT_IDS = frozenset((0x100, 0x101, 0x300, 0x301))
ECU_IDS = frozenset((0x110, 0x200, 0x210))

Frame = tuple[int, bytes]


class _Tick:
    __slots__ = ("plant", "command", "ecu")

    def __init__(self) -> None:
        self.plant: list[Frame] | None = None
        self.command: list[Frame] = []
        self.ecu: list[Frame] | None = None


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
        self.unknown_ids: Counter[int] = Counter()
        self.e2e: dict[str, Counter[str]] = {}
        self._checkers: dict[int, E2EChecker] = {}
        self.sensor_ticks = TickTracker()
        self.actuator_ticks = TickTracker()
        self.latest_sensor_tick = -1  # full tick of the newest PlantSensors heard
        self._plant_pending: list[Frame] = []
        self._ecu_pending: list[Frame] = []
        self._ticks: dict[int, _Tick] = {}
        self._bad: set[bytes] = set()
        self._sensor_wrap = TickUnwrapper()
        self._actuator_wrap = TickUnwrapper()

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
            if message.protected:
                self._checkers[message.frame_id] = message.checker(max_delta=14)
        names = list(self._columns)
        self._values = [math.nan] * len(names)
        self._scratch = [0.0] * 16
        self._trace_file: TextIO = (out_dir / "trace.csv").open("w", newline="")
        header = ["time[s]", "tick[-]", "command[%N or V]", "speed_true[%]", "speed_meas[%]"]
        header += [f"{n}[{u or '-'}]" for n, u in zip(names, units, strict=True)]
        self._trace_file.write(",".join(header) + "\n")
        # one preformatted row: %-formatting is several times faster than csv's float repr
        self._row_format = "%.6f,%d,%.9g,%.9g,%.9g," + ",".join(["%.9g"] * len(names)) + "\n"
        self.rows = 0

    # -- frames in -------------------------------------------------------------------------------
    def record(self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None) -> None:
        """A frame heard on the bus, or sent by the command node (see the module docstring)."""
        data = bytes(data)
        self._check(frame_id, data)
        if self.wall_clock:
            self._write(wall_s if wall_s is not None else 0.0, frame_id, data)
            if frame_id == ACTUATOR:
                self._end_row()
            return
        if frame_id in PLANT_IDS:
            self._plant_pending.append((frame_id, data))
            if frame_id == SENSORS:
                k = self._sensor_wrap.full(data[2] | data[3] << 8)
                self.latest_sensor_tick = max(self.latest_sensor_tick, k)
                self._slot(k).plant = self._plant_pending
                self._plant_pending = []
        elif frame_id in ECU_IDS:
            self._ecu_pending.append((frame_id, data))
            if frame_id == ACTUATOR:
                k = self._actuator_wrap.full(data[2] | data[3] << 8)
                self._slot(k).ecu = self._ecu_pending
                self._ecu_pending = []
        elif self.latest_sensor_tick < 0:  # before tick 0: the first demands
            self._write(0.0, frame_id, data)
            return
        else:  # the command node's frames (and foreign ones) go with the newest sensor tick
            self._slot(self.latest_sensor_tick).command.append((frame_id, data))
        if frame_id != SENSORS:
            # a tick completed by its sensor frame waits for the next frame: the command node's
            # answers to that sensor frame come first and belong to the tick
            self._flush_ready()

    def _slot(self, k: int) -> _Tick:
        slot = self._ticks.get(k)
        if slot is None:
            slot = self._ticks[k] = _Tick()
        return slot

    def _check(self, frame_id: int, data: bytes) -> None:
        """E2E and tick-sequence checks, in each sender's own order (as the frames arrive)."""
        self.frames += 1
        self.bits.add(frame_id, data)
        message = self.codec.by_id.get(frame_id)
        if message is None or len(data) != message.length:
            self.unknown_ids[frame_id] += 1
            return
        checker = self._checkers.get(frame_id)
        if checker is not None:
            status = checker.check(data)
            self.e2e.setdefault(message.name, Counter())[status.name] += 1
            if status == E2EStatus.WRONGCRC:
                self._bad.add(data)  # logged, never decoded into the trace
                return
        if frame_id == SENSORS:
            self.sensor_ticks.observe(data[2] | data[3] << 8)
        elif frame_id == ACTUATOR:
            self.actuator_ticks.observe(data[2] | data[3] << 8)

    # -- ticks out -------------------------------------------------------------------------------
    def _flush_ready(self) -> None:
        while True:
            slot = self._ticks.get(self.tick)
            if slot is None or slot.plant is None or slot.ecu is None:
                # a tick with a lost frame is written once a later one is complete
                if not any(
                    k > self.tick and s.plant is not None and s.ecu is not None
                    for k, s in self._ticks.items()
                ):
                    return
            self._write_tick(self._ticks.pop(self.tick, _Tick()))

    def _write_tick(self, slot: _Tick) -> None:
        seq = 0
        base = self.tick * self.period_s
        for group in (slot.plant or [], slot.command, slot.ecu or []):
            for frame_id, data in group:
                self._write(base + seq * _FRAME_SPACING_S, frame_id, data)
                seq += 1
        if slot.ecu is not None:
            self._end_row()
        else:
            self.tick += 1

    def _write(self, timestamp_s: float, frame_id: int, data: bytes) -> None:
        self.log.write(timestamp_s, frame_id, data)
        message = self.codec.by_id.get(frame_id)
        if message is None or len(data) != message.length:
            return
        if data in self._bad:
            self._bad.discard(data)
            return
        out = self._scratch
        message.unpack(data, out)
        if message.multiplexed:
            mux = message.mux_signals.get(int(out[0]))
            if mux is not None:
                self._values[self._columns[mux.name]] = out[1]
        else:
            for i, name in enumerate(message.signal_names):
                self._values[self._columns[name]] = out[i]

    def _end_row(self) -> None:
        v, c = self._values, self._columns
        k = self.tick
        command = (
            float(self.commands[k])
            if self.commands is not None and k < len(self.commands)
            else math.nan
        )
        self._trace_file.write(
            self._row_format
            % (
                k * self.period_s,
                k,
                command,
                100.0 * v[c["TrueSpeed"]] / N_MAX_RPM,
                100.0 * v[c["ShaftSpeed"]] / N_MAX_RPM,
                *v,
            )
        )
        self.rows += 1
        if self.rows % 1000 == 0:
            self._trace_file.flush()
            self.log.flush()
        self.tick += 1

    @property
    def missed_ticks(self) -> int:
        """Ticks lost, repeated or out of order, as seen in the sensor and actuator streams."""
        return sum(
            t.missing + t.repeated + t.out_of_order
            for t in (self.sensor_ticks, self.actuator_ticks)
        )

    def close(self) -> None:
        """Write whatever is still pending, in tick order, and close the files."""
        for k in sorted(self._ticks):
            if k >= self.tick:
                self.tick = k
                self._write_tick(self._ticks[k])
        self._ticks.clear()
        for frame_id, data in self._plant_pending + self._ecu_pending:
            self._write(self.tick * self.period_s, frame_id, data)
        self.log.close()
        if not self._trace_file.closed:
            self._trace_file.close()


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
