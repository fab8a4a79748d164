"""The recorder: every frame into ``can.log``, every signal per tick into ``trace.csv``.

It listens to the whole bus (or is handed the frames in-process), checks E2E on every protected
message, counts bits for the bus load, and keeps, sample-and-hold, the latest value of every DBC
signal. A tick ends with the ECU's actuator frame; the trace gets one row per tick. In lockstep
the timestamps are simulated time: the tick's start plus 10 us per frame within the tick.
Everything is written as it goes, so an aborted run keeps what it recorded.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import TextIO

from protocol.busload import BitCounter
from protocol.codec import Codec
from protocol.e2e import E2EChecker, E2EStatus
from protocol.lockstep import TickTracker
from sil.canlog import CandumpWriter

ACTUATOR = "EcuActuator"
N_MAX_RPM = 112_500.0
_FRAME_SPACING_S = 10e-6
_SKIP = ("_CRC", "_Counter")


class Recorder:
    def __init__(
        self,
        out_dir: Path,
        codec: Codec,
        period_s: float,
        *,
        channel: str = "vcan0",
        wall_clock: bool = False,
    ) -> None:
        self.codec = codec
        self.period_s = period_s
        self.wall_clock = wall_clock
        self.log = CandumpWriter(out_dir / "can.log", channel)
        self.tick = 0  # full tick count (the frames carry it modulo 2**16)
        self._seq = 0
        self.bits = BitCounter()
        self.frames = 0
        self.unknown_ids: Counter[int] = Counter()
        self.e2e: dict[str, Counter[str]] = {}
        self._checkers: dict[int, E2EChecker] = {}
        self.command = float("nan")
        self.sensor_ticks = TickTracker()
        self.actuator_ticks = TickTracker()

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
        self._values = [float("nan")] * len(names)
        self._scratch = [0.0] * 16
        self._trace_file: TextIO = (out_dir / "trace.csv").open("w", newline="")
        header = ["time[s]", "tick[-]", "command[%N or V]", "speed_true[%]", "speed_meas[%]"]
        header += [f"{n}[{u or '-'}]" for n, u in zip(names, units, strict=True)]
        self._trace_file.write(",".join(header) + "\n")
        # one preformatted row: %-formatting is several times faster than csv's float repr
        self._row_format = "%.6f,%d,%.9g,%.9g,%.9g," + ",".join(["%.9g"] * len(names)) + "\n"
        self.rows = 0

    def _timestamp(self, wall_s: float | None) -> float:
        if self.wall_clock and wall_s is not None:
            return wall_s
        return self.tick * self.period_s + self._seq * _FRAME_SPACING_S

    def record(self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None) -> None:
        """Log one frame (sent or received by anyone) and fold its signals into the state."""
        self.log.write(self._timestamp(wall_s), frame_id, data)
        self._seq += 1
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
                return
        out = self._scratch
        message.unpack(data, out)
        if message.multiplexed:
            self._values[self._columns[message.mux_signals[int(out[0])].name]] = out[1]
        else:
            for i, name in enumerate(message.signal_names):
                self._values[self._columns[name]] = out[i]
        if message.name == "PlantSensors":
            self.sensor_ticks.observe(int(out[0]))
        elif message.name == ACTUATOR:
            self.actuator_ticks.observe(int(out[message.signal_names.index("ActuatorTick")]))
            self._end_tick()

    def _end_tick(self) -> None:
        v, c = self._values, self._columns
        self._trace_file.write(
            self._row_format
            % (
                self.tick * self.period_s,
                self.tick,
                self.command,
                100.0 * v[c["TrueSpeed"]] / N_MAX_RPM,
                100.0 * v[c["ShaftSpeed"]] / N_MAX_RPM,
                *v,
            )
        )
        self.rows += 1
        if self.rows % 1000 == 0:
            self._trace_file.flush()
        self.tick += 1
        self._seq = 0

    @property
    def missed_ticks(self) -> int:
        """Ticks lost, repeated or out of order, as seen in the sensor and actuator streams."""
        return sum(
            t.missing + t.repeated + t.out_of_order
            for t in (self.sensor_ticks, self.actuator_ticks)
        )

    def value(self, name: str) -> float:
        """The latest value of a DBC signal."""
        return self._values[self._columns[name]]

    def close(self) -> None:
        self.log.close()
        if not self._trace_file.closed:
            self._trace_file.close()
