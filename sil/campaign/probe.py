"""A lean recorder for campaign runs: no files, one row per tick of what the metrics need.

It stands in for :class:`sil.recorder.Recorder` towards the command node (``record``,
``commands_sent``, ``tick``, ``latest_sensor_tick``) and keeps, sample-and-hold as the trace
does, the true speed of PlantTruthB, the ECU's reference speed, fault word and loop owner of
EcuStatus and the pump voltage and mode of EcuActuator; the plant's true speed and EGT are read
from the plant in process (``truth``), so invariants hold on the engine, not on what its sensors
claim.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from protocol.codec import Codec
from sil.recorder import ACTUATOR, N_MAX_RPM, InOrderTicks

Truth = Callable[[], tuple[float, float]]  # (true speed %N, true EGT K) now


class Probe(InOrderTicks):
    def __init__(self, codec: Codec, truth: Truth) -> None:
        self.truth = truth
        self._truth_b = codec["PlantTruthB"]
        self._status = codec["EcuStatus"]
        self._actuator = codec["EcuActuator"]
        self._ids = {
            self._truth_b.frame_id: self._on_truth_b,
            self._status.frame_id: self._on_status,
            ACTUATOR: self._on_actuator,
        }
        self._raw = [0] * 8
        super().__init__()  # a row per tick answered
        # sample-and-hold values
        self._speed = self._ref = math.nan
        self._fault_word = self._owner = 0
        # one entry per tick
        self.speed_pct: list[float] = []  # PlantTruthB true speed (as the trace's speed_true)
        self.ref_pct: list[float] = []
        self.n_pct: list[float] = []  # plant truth, read in process
        self.egt_k: list[float] = []
        self.fault_word: list[int] = []
        self.owner: list[int] = []
        self.mode: list[int] = []
        self.pump_v: list[float] = []

    def record(self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None) -> None:
        self.track(frame_id, data)
        handler = self._ids.get(frame_id)
        if handler is not None:
            handler(data)

    def commands_sent(self) -> None:
        """Nothing waits: in process the frames come in order and a row is taken per actuator
        frame."""

    def _on_truth_b(self, data: bytes | bytearray) -> None:
        self._truth_b.unpack_raw(data, self._raw)
        self._speed = 100.0 * self._raw[2] / N_MAX_RPM

    def _on_status(self, data: bytes | bytearray) -> None:
        raw = self._raw
        self._status.unpack_raw(data, raw)
        self._fault_word = raw[1]
        self._owner = raw[3]
        self._ref = raw[4] * 0.01

    def _on_actuator(self, data: bytes | bytearray) -> None:
        raw = self._raw
        self._actuator.unpack_raw(data, raw)
        n, egt = self.truth()
        self.speed_pct.append(self._speed)
        self.ref_pct.append(self._ref)
        self.n_pct.append(n)
        self.egt_k.append(egt)
        self.fault_word.append(self._fault_word)
        self.owner.append(self._owner)
        self.mode.append(raw[1])
        self.pump_v.append(raw[4] * 0.001)
