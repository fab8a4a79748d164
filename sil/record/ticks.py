"""The lockstep ticks on the bus, as the recorder and its stand-ins read them.

Which frames make a tick and in what order: each tick the plant's frames, PlantSensors(k), the
command node's frames, the ECU's, EcuActuator(k) (:func:`tick_block` checks a block of them);
and the full tick numbers read from the 16-bit ones the frames carry (:class:`TickUnwrapper`,
:class:`InOrderTicks`).
"""

from __future__ import annotations

import numpy as np

from protocol.lockstep import TICK_MODULO

SENSORS, ACTUATOR = 0x100, 0x110
PLANT_IDS = frozenset((0x100, 0x101, 0x300, 0x301, 0x302))
ECU_IDS = frozenset((0x110, 0x111, 0x200, 0x210))

# the frame classes in a tick, in their canonical order (tick_block)
_PLANT, _SENSORS, _OTHER, _ECU, _ACTUATOR = range(5)
_CLASS = np.full(0x800, _OTHER, np.int8)
_CLASS[[i for i in PLANT_IDS if i != SENSORS]] = _PLANT
_CLASS[SENSORS] = _SENSORS
_CLASS[[i for i in ECU_IDS if i != ACTUATOR]] = _ECU
_CLASS[ACTUATOR] = _ACTUATOR


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
    stand-ins for the :class:`~sil.record.recorder.Recorder` (the campaign's probe, the recorder
    process's feed)."""

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
