"""Replay logged CAN traffic: decode it (dry run) or play it onto a bus in real time.

Playback is scheduled against absolute time from the start (frame i goes out at
``start + (t_i - t_0) / speed``, gaps longer than ``skip_gaps`` shortened to it), so no drift
accumulates; the last millisecond before each frame is waited out by spinning, which keeps the
timing error well under a millisecond on an idle machine.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from protocol.codec import Codec
from protocol.e2e import E2EChecker, E2EStatus
from sil.record.canlog import LogReadError, read_frames

_SPIN_S = 0.0015


@dataclass
class LogStats:
    """What a pass over a log found, by message name or by reason."""

    frames: int = 0
    decoded: Counter[str] = field(default_factory=Counter)
    unknown_ids: Counter[int] = field(default_factory=Counter)
    wrong_length: Counter[str] = field(default_factory=Counter)  # wrong_length() text -> count
    skipped: Counter[str] = field(default_factory=Counter)  # reason -> count
    e2e: dict[str, Counter[str]] = field(default_factory=dict)  # message -> status -> count

    def as_dict(self) -> dict:
        return {
            "frames": self.frames,
            "decoded": dict(self.decoded),
            "unknown_ids": {f"0x{k:X}": v for k, v in sorted(self.unknown_ids.items())},
            "wrong_length": dict(self.wrong_length),
            "skipped": dict(self.skipped),
            "e2e_problems": {
                m: {s: n for s, n in c.items() if s != "OK"}
                for m, c in self.e2e.items()
                if set(c) - {"OK"}
            },
        }


def wrong_length(message, got: int) -> str:
    """How a frame of one of our messages (a codec message) with a wrong length is reported."""
    return (
        f"wrong length for {message.name} (0x{message.frame_id:03X}): "
        f"got {got}, expected {message.length}"
    )


def skip_reason(msg: can.Message) -> str | None:
    """Why a frame cannot be one of ours (and is not replayed into our nodes)."""
    if msg.is_error_frame:
        return "error frame"
    if msg.is_fd:
        return "CAN FD frame (the contract is classical CAN)"
    if msg.is_remote_frame:
        return "remote frame"
    return None


class Decoder:
    """Decodes our messages, checks their E2E protection and counts everything else."""

    def __init__(self, codec: Codec | None = None) -> None:
        self.codec = codec or Codec()
        self.stats = LogStats()
        self._checkers: dict[int, E2EChecker] = {
            m.frame_id: m.checker(max_delta=1) for m in self.codec.messages if m.protected
        }
        self._out = [0.0] * 16
        self.problem: str | None = None  # why the last frame was not decoded, if one of ours

    def decode(self, msg: can.Message) -> dict[str, float] | None:
        """The frame's signals by name, or None when it is not one of our messages (then
        :attr:`problem` says why, if its ID is one of ours)."""
        self.stats.frames += 1
        self.problem = None
        reason = skip_reason(msg)
        if reason is not None:
            self.stats.skipped[reason] += 1
            return None
        message = None if msg.is_extended_id else self.codec.by_id.get(msg.arbitration_id)
        if message is None:
            self.stats.unknown_ids[msg.arbitration_id] += 1
            return None
        if len(msg.data) != message.length:
            self.problem = wrong_length(message, len(msg.data))
            self.stats.wrong_length[self.problem] += 1
            return None
        checker = self._checkers.get(msg.arbitration_id)
        if checker is not None:
            status = checker.check(msg.data)
            self.stats.e2e.setdefault(message.name, Counter())[status.name] += 1
            if status == E2EStatus.WRONGCRC:
                return None
        self.stats.decoded[message.name] += 1
        message.unpack(msg.data, self._out)
        names = message.signal_names
        if message.multiplexed:
            names = (names[0], message.mux_signals[int(self._out[0])].name)
        return {name: self._out[i] for i, name in enumerate(names)}


def id_filter(spec: str | None) -> Callable[[int], bool]:
    """``0x100,0x110-0x1FF,512``: the IDs to keep (None keeps all)."""
    if not spec:
        return lambda _id: True
    ranges = []
    for part in spec.split(","):
        lo, _, hi = part.strip().partition("-")
        try:
            ranges.append((int(lo, 0), int(hi or lo, 0)))
        except ValueError:
            raise ValueError(f"ID filter '{part}' is not an ID or ID range (0x100-0x1FF)") from None
    return lambda frame_id: any(lo <= frame_id <= hi for lo, hi in ranges)


def schedule(
    frames: Iterable[can.Message], speed: float, skip_gaps: float | None
) -> Iterator[tuple[float, can.Message]]:
    """Each frame with its send time relative to the start of playback."""
    t0 = previous = None
    offset = 0.0
    for msg in frames:
        if t0 is None:
            t0 = previous = msg.timestamp
        gap = msg.timestamp - previous
        if skip_gaps is not None and gap > skip_gaps:
            offset += gap - skip_gaps
        previous = msg.timestamp
        yield (msg.timestamp - t0 - offset) / speed, msg


def wait_until(deadline: float, clock: Callable[[], float] = time.perf_counter) -> float:
    """Sleep, then spin, until ``deadline``; returns the clock at release."""
    while True:
        now = clock()
        remaining = deadline - now
        if remaining <= 0:
            return now
        if remaining > _SPIN_S:
            time.sleep(remaining - _SPIN_S)


@dataclass
class PlaybackReport:
    sent: int
    duration_s: float
    errors_s: np.ndarray

    def as_dict(self) -> dict:
        e = self.errors_s * 1e3
        pct = (lambda q: float(np.percentile(e, q))) if e.size else (lambda q: 0.0)
        return {
            "sent": self.sent,
            "duration_s": self.duration_s,
            "timing_error_ms": {
                "p50": pct(50),
                "p99": pct(99),
                "max": float(e.max()) if e.size else 0.0,
            },
        }


def play(
    path: Path,
    bus: can.BusABC,
    *,
    speed: float = 1.0,
    loop: bool = False,
    skip_gaps: float | None = None,
    keep: Callable[[int], bool] = lambda _id: True,
    should_stop: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.perf_counter,
) -> PlaybackReport:
    """Send a log's frames at their (scaled) times; timing error is measured at each send."""
    if speed <= 0:
        raise ValueError(f"speed {speed} must be positive")
    errors: list[float] = []
    start = clock()
    base = 0.0
    while True:
        last = 0.0
        frames = (m for m in read_frames(path) if skip_reason(m) is None and keep(m.arbitration_id))
        for t, msg in schedule(frames, speed, skip_gaps):
            if should_stop():
                loop = False
                break
            due = start + base + t
            sent_at = wait_until(due, clock)
            bus.send(msg)
            errors.append(sent_at - due)
            last = t
        if not loop:
            break
        base += last + 1e-3  # the next pass starts right after this one
    return PlaybackReport(len(errors), clock() - start, np.asarray(errors))


ECU_INPUTS = ("PlantSensors", "PlantAnalog", "Demand")
ECU_OUTPUTS = ("EcuActuator", "EcuStarter", "EcuStatus", "EcuTelemetry")


@dataclass
class EcuComparison:
    """Recorded ECU frames against the ones the emulator produced from the same inputs."""

    ticks: int = 0
    compared: int = 0
    differing: int = 0
    missing: int = 0  # recorded frames the emulator did not produce
    extra: int = 0  # frames the emulator produced beyond the recording
    first_divergent_tick: int | None = None
    # the first recorded ECU frame that differs: tick, time, message and its differing signals
    first_difference: dict | None = None
    max_difference: dict[str, float] = field(default_factory=dict)
    series: dict[str, tuple[list[float], list[float], list[float]]] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            "ticks": self.ticks,
            "frames_compared": self.compared,
            "frames_differing": self.differing,
            "frames_missing": self.missing,
            "frames_extra": self.extra,
            "first_divergent_tick": self.first_divergent_tick,
            "first_difference": self.first_difference,
            "max_difference": {k: v for k, v in self.max_difference.items() if v},
        }

    @property
    def differences(self) -> int:
        """Recorded ECU frames the emulator did not give alike: differing, missing or extra."""
        return self.differing + self.missing + self.extra

    def verdict(self) -> str | None:
        """One line on where the emulator first differs from the recording (None: nowhere)."""
        if not self.differences:
            return None
        counts = (
            f"{self.differing:,} of {self.compared:,} frames differing, {self.missing:,} "
            f"missing, {self.extra:,} extra"
        )
        first = self.first_difference
        if first is None:  # only frames beyond the recording
            return f"the ECU emulator sends frames the recording does not have ({counts})"
        if first["signals"]:
            name, (rec, emu) = next(iter(first["signals"].items()))
            what = f"{first['message']} {name}: recorded {rec:.9g}, replayed {emu:.9g}"
        else:
            what = f"{first['message']} {first.get('problem', 'differs')}"
        return (
            f"the ECU emulator differs from the recording from tick {first['tick']} "
            f"(t = {first['time_s']:.3f} s): {what} ({counts})"
        )

    def note_first(
        self, msg: can.Message, message, signals: dict, problem: str | None = None
    ) -> None:
        """Keep the first difference (``signals``: name -> (recorded, replayed))."""
        if self.first_difference is not None:
            return
        self.first_divergent_tick = self.ticks
        self.first_difference = {
            "tick": self.ticks,
            "time_s": msg.timestamp,
            "message": message.name,
            "signals": signals,
            **({"problem": problem} if problem else {}),
        }


def into_ecu(
    path: Path, node, *, trace_signals: tuple[str, ...] = ("PumpVoltageTarget",)
) -> EcuComparison:
    """Drive an ECU node with a log's sensor, analog and demand frames, in recorded order, and
    compare every frame it sends with the ECU frames recorded in the log (n-th with n-th, by ID).

    ``node`` is a sans-IO ECU node (:class:`ecu.node.EcuNode`) in lockstep mode.
    """
    codec = Codec()
    inputs = {codec[name].frame_id for name in ECU_INPUTS}
    outputs = {codec[name].frame_id: codec[name] for name in ECU_OUTPUTS}
    produced: dict[int, deque] = {fid: deque() for fid in outputs}
    actuator_id = codec["EcuActuator"].frame_id

    def send(frame_id: int, data: bytes | bytearray) -> None:
        if frame_id in produced:
            produced[frame_id].append(bytes(data))

    report = EcuComparison()
    a, b = [0.0] * 16, [0.0] * 16
    node.start(send)
    reader = read_frames(path)
    for msg in reader:
        if skip_reason(msg) is not None or msg.is_extended_id:
            continue
        frame_id = msg.arbitration_id
        ours = codec.by_id.get(frame_id)
        if ours is not None and len(msg.data) != ours.length:
            reason = wrong_length(ours, len(msg.data))
            raise LogReadError(path, reader.position, reason, reader.frames - 1)
        if frame_id in inputs:
            node.on_frame(frame_id, msg.data, send)
            continue
        message = outputs.get(frame_id)
        if message is None:
            continue
        queue = produced[frame_id]
        if not queue:
            report.missing += 1
            report.note_first(msg, message, {}, "missing: the emulator did not send it")
            continue
        mine = queue.popleft()
        report.compared += 1
        message.unpack(msg.data, a)
        message.unpack(mine, b)
        names = message.signal_names
        if message.multiplexed:
            names = (names[0], message.mux_signals[int(a[0])].name)
        if bytes(msg.data[1:]) != mine[1:]:  # byte 0 is the CRC, which follows the rest
            report.differing += 1
            for i, name in enumerate(names):
                report.max_difference[name] = max(
                    report.max_difference.get(name, 0.0), abs(a[i] - b[i])
                )
            differing = {n: (a[i], b[i]) for i, n in enumerate(names) if a[i] != b[i]}
            report.note_first(msg, message, differing)
        for i, name in enumerate(names):
            if name in trace_signals:
                t, rec, emu = report.series.setdefault(name, ([], [], []))
                t.append(msg.timestamp)
                rec.append(a[i])
                emu.append(b[i])
        if frame_id == actuator_id:
            report.ticks += 1
    report.extra = sum(len(q) for q in produced.values())
    return report
