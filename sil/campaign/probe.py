"""A lean recorder for campaign runs: no files, one row per tick of what the metrics need.

It stands in for :class:`sil.record.recorder.Recorder` towards the command node (``record``,
``commands_sent``, ``tick``, ``latest_sensor_tick``) and keeps, sample-and-hold as the trace
does, the true speed of PlantTruthB, the fuel delivered without a flame of PlantTruthC, the ECU's
reference speed, fault word and loop owner of EcuStatus, the sequencer's state and abort reason
of EcuStarter and the pump voltage and mode of EcuActuator; the plant's true speed, EGT, P3,
thrust and flags are read from the plant in process (``truth``), so invariants hold on the
engine, not on what its sensors claim.

A run in the compiled loop (sil/run/compiled_loop.py, the C ECU) hands the frames over in blocks
(:meth:`Probe.record_ticks`, decoded vectorised to the same rows) and the plant's truth per tick
afterwards (:meth:`Probe.take_truth`), as the loop kept it when the ECU answered each tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from protocol.codec import Codec
from sil.record.ticks import ACTUATOR, InOrderTicks
from sil.record.trace_writer import N_MAX_RPM, raw_field

Truth = Callable[[], tuple[float, float, float, float, int]]  # (N %, EGT K, P3 Pa, thrust N, flags)


class Probe(InOrderTicks):
    def __init__(self, codec: Codec, truth: Truth) -> None:
        self.truth = truth
        self._truth_b = codec["PlantTruthB"]
        self._truth_c = codec["PlantTruthC"]
        self._status = codec["EcuStatus"]
        self._starter = codec["EcuStarter"]
        self._actuator = codec["EcuActuator"]
        self._ids = {
            self._truth_b.frame_id: self._on_truth_b,
            self._truth_c.frame_id: self._on_truth_c,
            self._status.frame_id: self._on_status,
            self._starter.frame_id: self._on_starter,
            ACTUATOR: self._on_actuator,
        }
        self._raw = [0] * 8
        super().__init__()  # a row per tick answered
        # sample-and-hold values
        self._speed = self._ref = math.nan
        self._fault_word = self._owner = 0
        self._unburnt = 0.0
        self._seq_state = self._reason = 0
        # one entry per tick
        self.speed_pct: list[float] = []  # PlantTruthB true speed (as the trace's speed_true)
        self.ref_pct: list[float] = []
        self.n_pct: list[float] = []  # plant truth, read in process
        self.egt_k: list[float] = []
        self.p3_pa: list[float] = []
        self.thrust_n: list[float] = []
        self.flags: list[float] = []  # (float: NaN until the compiled loop's truth is taken)
        self.fault_word: list[int] = []
        self.owner: list[int] = []
        self.mode: list[int] = []
        self.pump_v: list[float] = []
        self.unburnt_kg: list[float] = []  # PlantTruthC: fuel delivered without a flame
        self.seq_state: list[int] = []  # EcuStarter (held while the ECU does not send it)
        self.abort_reason: list[int] = []

    def record(self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None) -> None:
        self.track(frame_id, data)
        handler = self._ids.get(frame_id)
        if handler is not None:
            handler(data)

    def record_ticks(self, frame_ids: np.ndarray, payload: np.ndarray) -> None:
        """:meth:`record` of every frame of a block ((frames, 8) uint8 payload), vectorised: a
        row per EcuActuator; the rows' true speed and EGT stay NaN until :meth:`take_truth`."""
        ids = np.asarray(frame_ids)
        data = np.ascontiguousarray(payload, np.uint8)
        self.track_many(ids, data)
        words = data.view("<u8").ravel()
        rows = np.flatnonzero(ids == ACTUATOR)
        if not len(rows):
            return
        truth_b, status = self._truth_b, self._status
        speed, self._speed = _held(ids, words, rows, truth_b, 2, self._speed, _percent_n)
        ref, self._ref = _held(ids, words, rows, status, 4, self._ref, _centi)
        fault_word, held_word = _held(ids, words, rows, status, 1, self._fault_word, _same)
        owner, held_owner = _held(ids, words, rows, status, 3, self._owner, _same)
        self._fault_word, self._owner = int(held_word), int(held_owner)
        unburnt, self._unburnt = _held(ids, words, rows, self._truth_c, 3, self._unburnt, _micro)
        starter = self._starter
        seq_state, held_state = _held(ids, words, rows, starter, 3, self._seq_state, _same)
        reason, held_reason = _held(ids, words, rows, starter, 4, self._reason, _same)
        self._seq_state, self._reason = int(held_state), int(held_reason)
        self.unburnt_kg += unburnt.tolist()
        self.seq_state += seq_state.astype(np.int64).tolist()
        self.abort_reason += reason.astype(np.int64).tolist()
        self.speed_pct += speed.tolist()
        self.ref_pct += ref.tolist()
        self.fault_word += fault_word.astype(np.int64).tolist()
        self.owner += owner.astype(np.int64).tolist()
        self.mode += _field(words[rows], self._actuator, 1).tolist()
        self.pump_v += (_field(words[rows], self._actuator, 4) * 0.001).tolist()
        for column in (self.n_pct, self.egt_k, self.p3_pa, self.thrust_n, self.flags):
            column += [math.nan] * len(rows)

    def take_truth(self, truth: np.ndarray) -> None:
        """The plant's truth per row as the loop kept it ((rows, 5): N %, EGT K, P3 Pa, thrust N,
        flags)."""
        n = len(self.n_pct)
        self.n_pct, self.egt_k, self.p3_pa, self.thrust_n, self.flags = truth[:n, :5].T.tolist()

    def commands_sent(self) -> None:
        """Nothing waits: in process the frames come in order and a row is taken per actuator
        frame."""

    def _on_truth_b(self, data: bytes | bytearray) -> None:
        self._truth_b.unpack_raw(data, self._raw)
        self._speed = 100.0 * self._raw[2] / N_MAX_RPM

    def _on_truth_c(self, data: bytes | bytearray) -> None:
        self._truth_c.unpack_raw(data, self._raw)
        self._unburnt = self._raw[3] * 1e-6

    def _on_starter(self, data: bytes | bytearray) -> None:
        self._starter.unpack_raw(data, self._raw)
        self._seq_state = self._raw[3]
        self._reason = self._raw[4]

    def _on_status(self, data: bytes | bytearray) -> None:
        raw = self._raw
        self._status.unpack_raw(data, raw)
        self._fault_word = raw[1]
        self._owner = raw[3]
        self._ref = raw[4] * 0.01

    def _on_actuator(self, data: bytes | bytearray) -> None:
        raw = self._raw
        self._actuator.unpack_raw(data, raw)
        n, egt, p3, thrust, flags = self.truth()
        self.speed_pct.append(self._speed)
        self.ref_pct.append(self._ref)
        self.n_pct.append(n)
        self.egt_k.append(egt)
        self.p3_pa.append(p3)
        self.thrust_n.append(thrust)
        self.flags.append(float(flags))
        self.fault_word.append(self._fault_word)
        self.owner.append(self._owner)
        self.mode.append(raw[1])
        self.pump_v.append(raw[4] * 0.001)
        self.unburnt_kg.append(self._unburnt)
        self.seq_state.append(self._seq_state)
        self.abort_reason.append(self._reason)


def _percent_n(raw: np.ndarray) -> np.ndarray:
    return 100.0 * raw / N_MAX_RPM  # (as _on_truth_b)


def _micro(raw: np.ndarray) -> np.ndarray:
    return raw * 1e-6  # (as _on_truth_c)


def _centi(raw: np.ndarray) -> np.ndarray:
    return raw * 0.01  # (as _on_status)


def _same(raw: np.ndarray) -> np.ndarray:
    return raw


def _held(ids, words, rows, message, i: int, held: float, convert) -> tuple[np.ndarray, float]:  # noqa: ANN001
    """Per row (an index into the block), ``convert`` of raw field i of the last frame of
    ``message`` before it, else ``held``; and the value held after the block."""
    at = np.flatnonzero(ids == message.frame_id)
    last = np.searchsorted(at, rows) - 1  # (into ``at``)
    values = np.full(len(rows), held, np.float64)
    got = last >= 0
    if got.any():
        values[got] = convert(_field(words[at[last[got]]], message, i))
    return values, float(values[-1])


def _field(words: np.ndarray, message, i: int) -> np.ndarray:  # noqa: ANN001
    """Raw field i of a message in 64-bit little-endian frame words."""
    start, mask, sign_bit, _lo, _hi = message._fields[i]
    return raw_field(words, start, mask, sign_bit)
