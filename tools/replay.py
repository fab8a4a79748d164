"""Replay logged CAN traffic: decode it (dry run) or play it onto a bus in real time.

Playback is scheduled against absolute time from the start (frame i goes out at
``start + (t_i - t_0) / speed``, gaps longer than ``skip_gaps`` shortened to it), so no drift
accumulates; the last millisecond before each frame is waited out by spinning, which keeps the
timing error well under a millisecond on an idle machine.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from protocol.codec import Codec
from protocol.e2e import E2EChecker, E2EStatus
from sil.canlog import read_frames

_SPIN_S = 0.0015


@dataclass
class LogStats:
    """What a pass over a log found, by message name or by reason."""

    frames: int = 0
    decoded: Counter[str] = field(default_factory=Counter)
    unknown_ids: Counter[int] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)  # reason -> count
    e2e: dict[str, Counter[str]] = field(default_factory=dict)  # message -> status -> count

    def as_dict(self) -> dict:
        return {
            "frames": self.frames,
            "decoded": dict(self.decoded),
            "unknown_ids": {f"0x{k:X}": v for k, v in sorted(self.unknown_ids.items())},
            "skipped": dict(self.skipped),
            "e2e_problems": {
                m: {s: n for s, n in c.items() if s != "OK"}
                for m, c in self.e2e.items()
                if set(c) - {"OK"}
            },
        }


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

    def decode(self, msg: can.Message) -> dict[str, float] | None:
        """The frame's signals by name, or None when it is not one of our messages."""
        self.stats.frames += 1
        reason = skip_reason(msg)
        if reason is not None:
            self.stats.skipped[reason] += 1
            return None
        message = None if msg.is_extended_id else self.codec.by_id.get(msg.arbitration_id)
        if message is None or len(msg.data) != message.length:
            self.stats.unknown_ids[msg.arbitration_id] += 1
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
