"""The engine's live values from the CAN contract's frames, as the ground-support page shows
them: the latest of each signal, a 60 s history at 10 Hz for the chart, and the faults seen
(a fault bit that rose, a start aborted) with a snapshot of the values at that moment.

Frames come from any bus (:meth:`Live.feed`, called by the bus reader); values are decoded with
the DBC (cantools), enumerations by its value tables. Speed and EGT are the sensor frames the
ECU reads (``PlantSensors``), the rest is what the ECU says of itself (``EcuStatus``,
``EcuActuator``, ``EcuStarter``) and the analog frame (``PlantAnalog``).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field

import can
import cantools

from ecu import faults
from ecu.firmware import RPM_PER_PCT
from protocol.dbc import load_database

HISTORY_S = 60.0
HISTORY_HZ = 10.0
SILENT_S = 0.5  # the ECU's status frame older than this: the ECU is silent
FAULT_LOG_MAX = 200
INFORMATION = faults.LIMITER_ACTIVE | faults.PUMP_SATURATED  # not logged: the loops at work
# signals shown, by frame: (signal, key on the page)
SHOWN = {
    "PlantSensors": (("ShaftSpeed", "speed_rpm"), ("EGT", "egt_k")),
    "PlantAnalog": (("SupplyVoltage", "supply_v"), ("PumpCurrent", "pump_current_a")),
    "EcuActuator": (
        ("PumpEnable", "pump_enable"),
        ("PumpDuty", "pump_duty_pct"),
        ("PumpVoltageTarget", "pump_v"),
    ),
    "EcuStarter": (
        ("IgniterOn", "igniter"),
        ("StarterDuty", "starter_pct"),
        ("SequencerState", "step"),
        ("AbortReason", "abort_reason"),
    ),
    "EcuStatus": (
        ("EcuMode", "state"),
        ("FaultWord", "fault_word"),
        ("PumpHealth", "pump_health_pct"),
        ("LoopOwner", "owner"),
        ("ReferenceSpeed", "speed_ref_pct"),
        ("SensorsValid", "sensors_valid"),
    ),
    "Demand": (("SpeedDemand", "can_demand_pct"),),
}


@dataclass
class FaultEntry:
    """A fault bit that came up, with the values at that moment."""

    wall_s: float
    bits: list[str]
    word: int
    snapshot: dict


@dataclass
class Live:
    """The latest values and their history; thread-safe (the bus reader feeds, the server
    reads)."""

    db: cantools.database.Database = field(default_factory=load_database)
    values: dict = field(default_factory=dict)
    frames: int = 0
    undecodable: int = 0
    status_s: float = 0.0  # wall clock of the newest EcuStatus
    running_since_s: float = 0.0  # ... of the first EcuStatus after a silence
    history: deque = field(default_factory=lambda: deque(maxlen=int(HISTORY_S * HISTORY_HZ)))
    fault_log: deque = field(default_factory=lambda: deque(maxlen=FAULT_LOG_MAX))
    recorder: list[can.Message] | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _next_sample_s: float = 0.0
    _fault_word: int = 0  # the last status frame's fault word
    _abort: object = None  # the last starter frame's abort reason (None: none seen yet)
    _ids: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._ids = {
            self.db.get_message_by_name(name).frame_id: (self.db.get_message_by_name(name), pairs)
            for name, pairs in SHOWN.items()
        }

    def feed(self, msg: can.Message, now_s: float | None = None) -> None:
        """One frame from the bus, received at ``now_s`` (wall clock)."""
        now_s = time.time() if now_s is None else now_s
        with self._lock:
            self.frames += 1
            if self.recorder is not None:
                msg.timestamp = now_s  # (the nodes' own stamps may count simulated time)
                self.recorder.append(msg)
            known = self._ids.get(msg.arbitration_id)
            if known is None or msg.is_error_frame or msg.is_remote_frame:
                return
            message, pairs = known
            try:
                decoded = message.decode(bytes(msg.data), decode_choices=True)
            except (ValueError, KeyError, cantools.database.errors.DecodeError):
                self.undecodable += 1
                return
            for signal, key in pairs:
                value = decoded.get(signal)
                self.values[key] = value if isinstance(value, int | float) else str(value)
            if message.name == "EcuStatus":
                self._status(now_s)
            if message.name == "EcuStarter":
                self._abort_seen(now_s)
            if message.name == "PlantSensors":
                self.values["speed_pct"] = self.values["speed_rpm"] / RPM_PER_PCT
                self.values["frame_s"] = now_s
            if now_s >= self._next_sample_s:
                self._next_sample_s = now_s + 1.0 / HISTORY_HZ
                self.history.append(self._sample(now_s))

    def _status(self, now_s: float) -> None:
        word = int(self.values.get("fault_word", 0))
        new = word & ~self._fault_word & ~INFORMATION
        self._fault_word = word
        self.values["faults"] = faults.names(word)
        if now_s - self.status_s > SILENT_S:
            self.running_since_s = now_s
        self.status_s = now_s
        if new:
            self._log(now_s, faults.names(new))

    def _abort_seen(self, now_s: float) -> None:
        """A start aborted: the starter frame's abort reason changed to one (its first value
        is the last start's, from before the page watched)."""
        reason = self.values.get("abort_reason")
        before, self._abort = self._abort, reason
        if before is not None and reason != before and reason not in ("NONE", 0):
            self._log(now_s, [f"START_ABORT_{reason}"])

    def _log(self, now_s: float, bits: list[str]) -> None:
        word = int(self.values.get("fault_word", 0))
        self.fault_log.append(FaultEntry(now_s, bits, word, dict(self.values)))

    def _sample(self, now_s: float) -> list:
        v = self.values
        return [
            round(now_s, 3),
            v.get("speed_pct"),
            v.get("speed_ref_pct"),
            v.get("egt_k"),
            v.get("pump_v"),
        ]

    def snapshot(self, now_s: float | None = None) -> dict:
        """What the page shows now, as plain JSON values."""
        now_s = time.time() if now_s is None else now_s
        with self._lock:
            out = dict(self.values)
            out["frames"] = self.frames
            out["undecodable"] = self.undecodable
            out["ecu_silent"] = now_s - self.status_s > SILENT_S
            out["recording"] = self.recorder is not None
            out["recorded_frames"] = len(self.recorder) if self.recorder is not None else 0
            return out

    def running_for(self, now_s: float | None = None) -> float:
        """How long the ECU's status frames have come without a silence (0: silent now)."""
        now_s = time.time() if now_s is None else now_s
        with self._lock:
            if now_s - self.status_s > SILENT_S:
                return 0.0
            return now_s - self.running_since_s

    def chart(self) -> list[list]:
        with self._lock:
            return list(self.history)

    def faults_seen(self) -> list[dict]:
        with self._lock:
            return [
                {"wall_s": e.wall_s, "bits": e.bits, "word": e.word, "snapshot": e.snapshot}
                for e in self.fault_log
            ]

    def start_recording(self, kept: list[can.Message] | None = None) -> bool:
        """Keep every frame from now on (after ``kept``, the frames of a recording that could
        not be written); False if a recording is already under way."""
        with self._lock:
            if self.recorder is not None:
                return False
            self.recorder = kept if kept is not None else []
            return True

    def stop_recording(self) -> list[can.Message] | None:
        """The frames kept since :meth:`start_recording` (None: none under way)."""
        with self._lock:
            frames, self.recorder = self.recorder, None
            return frames
