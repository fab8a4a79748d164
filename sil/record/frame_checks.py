"""The checks of the frames a recorder hears, in the order they arrived, made in bulk.

E2E on every protected message (table CRC-8, alive counter: the verdicts of ``E2EChecker`` with
any change of the counter accepted), the tick sequences of PlantSensors and EcuActuator, and
the frames of IDs not in the contract or of the wrong length, counted per ID.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from protocol.codec import Codec
from protocol.e2e import COUNTER_MODULO, E2EStatus, crc8_rows, data_id_crc_start
from protocol.lockstep import TICK_MODULO, TickTracker
from sil.record.ticks import ACTUATOR, SENSORS

_STATUS_NAMES = [s.name for s in E2EStatus]


class FrameChecks:
    """The verdicts on the frames checked so far; :meth:`check` takes the next ones."""

    def __init__(self, codec: Codec) -> None:
        self.unknown_ids: Counter[int] = Counter()  # frames of IDs not in the contract, per ID
        self.wrong_length: Counter[int] = Counter()  # of IDs in it but another length, per ID
        # SensorTick and ActuatorTick of every PlantSensors and EcuActuator that passed E2E
        self.sensor_ticks = TickTracker()
        self.actuator_ticks = TickTracker()
        # per frame ID: (length, E2E state or None); E2E state: [CRC start, last counter,
        # counts per status, message name]
        self.known: dict[int, tuple[int, list | None]] = {}
        self._e2e_seen: list[tuple[str, int]] = []  # (message, status) in order of first count
        for message in codec.messages:
            state = None
            if message.protected:
                state = [data_id_crc_start(message.data_id), -1, [0] * len(E2EStatus), message.name]
            self.known[message.frame_id] = (message.length, state)
        # the same per 11-bit ID, for lookups in bulk: the message's length, -1 for no message
        self._length_of = np.full(0x800, -1, np.int64)
        for frame_id, (length, _) in self.known.items():
            if 0 <= frame_id < 0x800:
                self._length_of[frame_id] = length

    @property
    def e2e(self) -> dict[str, Counter[str]]:
        """E2E verdicts per message name (only messages heard, only verdicts given)."""
        out: dict[str, Counter[str]] = {}
        counts = {state[3]: state[2] for _, state in self.known.values() if state is not None}
        for name, status in self._e2e_seen:
            out.setdefault(name, Counter())[_STATUS_NAMES[status]] = counts[name][status]
        return out

    def check(self, ids: np.ndarray, payload: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """E2E and tick-sequence checks of frames heard one after the other (after those checked
        before), unknown IDs and wrong lengths counted; returns the indices of the frames with a
        bad CRC."""
        inside = (ids >= 0) & (ids < 0x800)
        if inside.all():  # known ID, right length, E2E not WRONGCRC
            good = self._length_of[ids] == lengths
        else:
            good = np.zeros(len(ids), bool)
            good[inside] = self._length_of[ids[inside]] == lengths[inside]
            for frame_id, (length, _) in self.known.items():
                if not 0 <= frame_id < 0x800:
                    good |= (ids == frame_id) & (lengths == length)
        if not good.all():
            for frame_id in ids[~good].tolist():
                known = frame_id in self.known
                (self.wrong_length if known else self.unknown_ids)[frame_id] += 1
        present = set(np.unique(ids[good]).tolist())
        seen: list[tuple[int, str, int]] = []
        bad: list[np.ndarray] = []
        for frame_id, (length, state) in self.known.items():
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
        for frame_id, tracker in ((SENSORS, self.sensor_ticks), (ACTUATOR, self.actuator_ticks)):
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
