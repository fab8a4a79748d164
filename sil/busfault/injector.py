"""The per-frame decisions of the bus fault injector, deterministic for a seed.

``transmit(tick, frame_id, data)`` returns what reaches the receivers for a frame sent at
``tick`` (an ECU period): a list of copies, each with the tick it is released at and, for a
faulted copy, the event that logs it. ``flood(tick)`` gives a babbling node's frames for a tick.
Every fault applied is logged in ``events`` with its tick and time, so a report can pair it with
the ECU's reaction. Each fault draws from its own generator seeded by (seed, its index), so
adding a fault does not change the draws of the others.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from protocol.codec import Codec
from protocol.e2e import protect
from sil.busfault.spec import BusFault


@dataclass
class Copy:
    release_tick: int
    data: bytes
    event: dict | None = None  # the logged event of a faulted copy


@dataclass
class _Window:
    fault: BusFault
    index: int
    start: int
    end: int
    rng: random.Random
    data_ids: dict[int, int]  # frame ID -> E2E data ID
    burst_left: int = 0
    frozen: dict[int, int] = field(default_factory=dict)  # frame ID -> frozen counter
    held: dict[int, bytes] = field(default_factory=dict)  # reorder: frame ID -> held frame

    def covers(self, tick: int, frame_id: int) -> bool:
        return self.start <= tick < self.end and (not self.fault.ids or frame_id in self.fault.ids)


class Injector:
    def __init__(
        self, faults: tuple[BusFault, ...], rate_hz: float, seed: int, codec: Codec | None = None
    ) -> None:
        codec = codec or Codec()
        data_ids = {m.frame_id: m.data_id for m in codec.messages if m.protected}
        self.rate_hz = rate_hz
        self.windows = [
            _Window(f, i, *f.window(rate_hz), random.Random(seed * 7919 + i), data_ids)
            for i, f in enumerate(faults)
        ]
        self.events: list[dict] = []
        # before the first window and after the last, a frame passes unchanged (unless a
        # reorder window still holds one)
        self._first = min((w.start for w in self.windows), default=0)
        self._last = max((w.end for w in self.windows), default=0)
        self._reorders = [w for w in self.windows if w.fault.kind == "reorder"]

    def quiet(self, tick: int) -> bool:
        """No fault acts at ``tick``: ``transmit`` passes every frame sent then unchanged."""
        return (tick < self._first or tick >= self._last) and not any(
            w.held for w in self._reorders
        )

    def _log(self, w: _Window, tick: int, frame_id: int, action: str) -> dict:
        event = {
            "fault": w.index,
            "kind": w.fault.kind,
            "tick": tick,
            "time_s": tick / self.rate_hz,
            "id": frame_id,
            "action": action,
        }
        self.events.append(event)
        return event

    def transmit(self, tick: int, frame_id: int, data: bytes) -> list[Copy]:
        copies = [Copy(tick, data)]
        for w in self.windows:
            if w.fault.kind == "babble":
                if w.fault.starve and w.start <= tick < w.end and frame_id > w.fault.ids[0]:
                    self._log(w, tick, frame_id, "starved")
                    return []
                continue
            if frame_id in w.held and not w.covers(tick, frame_id):  # reorder window ended
                copies.append(Copy(tick, w.held.pop(frame_id)))
            if w.covers(tick, frame_id):
                copies = [c for old in copies for c in self._apply(w, tick, frame_id, old)]
        return copies

    def _apply(self, w: _Window, tick: int, frame_id: int, c: Copy) -> list[Copy]:
        f, rng = w.fault, w.rng
        kind = f.kind
        if kind == "bus_off":
            self._log(w, tick, frame_id, "lost")
            return []
        if kind == "drop":
            if w.burst_left == 0 and rng.random() < f.rate:
                w.burst_left = f.burst
            if w.burst_left:
                w.burst_left -= 1
                self._log(w, tick, frame_id, "dropped")
                return []
            return [c]
        if kind == "delay":
            release = (
                tick + f.delay_ticks + (rng.randint(0, f.jitter_ticks) if f.jitter_ticks else 0)
            )
            event = self._log(w, tick, frame_id, f"delayed {release - tick} ticks")
            return [Copy(release, c.data, event)]
        if kind == "duplicate":
            if rng.random() < f.rate:
                return [c, Copy(c.release_tick, c.data, self._log(w, tick, frame_id, "duplicated"))]
            return [c]
        if kind == "reorder":
            held = w.held.pop(frame_id, None)
            if held is not None:
                return [c, Copy(c.release_tick, held, self._log(w, tick, frame_id, "reordered"))]
            if rng.random() < f.rate:
                w.held[frame_id] = c.data
                return []
            return [c]
        if kind == "bitflip":
            if rng.random() >= f.rate:
                return [c]
            frame = bytearray(c.data)
            for bit in rng.sample(range(8, 8 * len(frame)), f.bits):  # bytes 1..7
                frame[bit // 8] ^= 1 << (bit % 8)
            return [Copy(c.release_tick, bytes(frame), self._log(w, tick, frame_id, "bit flip"))]
        if kind == "freeze_counter":
            data_id = w.data_ids.get(frame_id)
            if data_id is None:
                return [c]
            counter = w.frozen.setdefault(frame_id, c.data[1] & 0x0F)
            if c.data[1] & 0x0F == counter:
                return [c]  # the first frame of the window carries the counter that freezes
            frame = bytearray(c.data)
            protect(frame, data_id, counter)  # the sender's counter is stuck, its CRC is right
            return [Copy(c.release_tick, bytes(frame), self._log(w, tick, frame_id, "counter"))]
        raise AssertionError(kind)

    def flood(self, tick: int) -> list[tuple[int, bytes, dict]]:
        """A babbling node's frames at this tick: random payloads on the fault's first ID."""
        out = []
        for w in self.windows:
            f = w.fault
            if f.kind == "babble" and w.start <= tick < w.end:
                for _ in range(f.flood_per_tick):
                    data = w.rng.randbytes(8)
                    out.append((f.ids[0], data, self._log(w, tick, f.ids[0], "babble")))
        return out
