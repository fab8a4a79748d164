"""The command node: plays a scenario's demands and fault injections, and records the run.

It follows the lockstep rules of :mod:`protocol.lockstep`: on PlantSensors(k) it sends the Demand
for tick k + L (L = one demand period) and, before it, any FaultInject due at that tick, so both
are on the bus before the ECU can answer tick k + L. It hears every frame and hands it, with the
frames it sends itself, to the :class:`~sil.record.recorder.Recorder` (or, in process and in
lockstep, to the :class:`~sil.run.recorder_process.RecorderProcess`). It is finished once the ECU
has answered the last tick.

On a bus it also sends its run's SimRun beacon (:mod:`protocol.run_bus`) about once a second of
simulated time, with the demand of that tick; the beacon is not the run's traffic, so it is not
recorded.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from protocol.codec import Codec
from protocol.lockstep import TICK_MODULO, demand_lead_ticks, every_ticks
from protocol.node import SendFn
from protocol.run_bus import SIMRUN_ID, simrun_payload
from sil.record.recorder import Recorder
from sil.record.ticks import SENSORS
from sil.run.recorder_process import RecorderProcess
from sil.scenario import Fault, fault_targets


class CommandNode:
    def __init__(
        self,
        codec: Codec,
        recorder: Recorder | RecorderProcess,
        commands: np.ndarray,
        *,
        ecu_rate_hz: float,
        open_loop: bool,
        faults: tuple[Fault, ...] = (),
        progress=None,
        realtime: bool = False,
        run_id: int | None = None,
        stop_tick: int | None = None,
    ) -> None:
        self.codec = codec
        self.recorder = recorder
        self.commands = commands  # the command at every tick 0..ticks
        self.last_tick = len(commands) - 1
        self.open_loop = open_loop
        self.stop_tick = stop_tick  # from this tick: arm released, stop requested (None: never)
        self.demand = codec["Demand"]
        self.fault_msg = codec["FaultInject"]
        self.every = every_ticks(self.demand.cycle_time_ms, ecu_rate_hz)
        self.lead = demand_lead_ticks(self.every)
        self.run_id = run_id  # None: no beacon (no bus)
        self.beacon_every = self.every * max(1, round(ecu_rate_hz / self.every))
        targets = {name: i for i, name in enumerate(fault_targets())}
        # each fault at the first demand tick at or after its time (see the module docstring)
        self.faults: dict[int, list[tuple[int, float]]] = {}
        for f in faults:
            tick = math.ceil(f.time_s * ecu_rate_hz / self.every) * self.every
            self.faults.setdefault(tick, []).append((targets[f.target], f.value))
        self.injected: list[dict] = []
        self.progress = progress
        self.realtime = realtime
        self.own_tick = 0  # real time: the command node's own clock, in ECU periods
        self.next_play = 0  # lockstep: the next demand tick to send
        self.finished = False
        self._wall_s: float | None = None

    def _sent(self, send: SendFn, frame_id: int, data: bytearray) -> None:
        send(frame_id, data)
        self.recorder.record(frame_id, data, self._wall_s)

    def _play(self, tick: int, send: SendFn) -> None:
        """Send what is due at ``tick``: the beacon, fault injections, then the demand."""
        if self.run_id is not None and tick % self.beacon_every == 0:
            send(SIMRUN_ID, simrun_payload(self.run_id, tick))
        for frame_id, data in self.frames_at(tick):
            self._sent(send, frame_id, data)
        self.injected += self.injections_at(tick)

    def frames_at(self, tick: int) -> Iterator[tuple[int, bytearray]]:
        """The frames due at ``tick`` in sending order (each packed when it is reached, into a
        buffer the next one reuses)."""
        for target, value in self.faults.get(tick, ()):
            self.fault_msg.pack([target, tick % TICK_MODULO, value])
            yield self.fault_msg.frame_id, self.fault_msg.data
        command = float(self.commands[tick])
        speed, volts = (0.0, command) if self.open_loop else (command, 0.0)
        stop = self.stop_tick is not None and tick >= self.stop_tick
        self.demand.pack([0 if stop else 1, 1 if stop else 0, speed, volts, tick % TICK_MODULO])
        yield self.demand.frame_id, self.demand.data

    def injections_at(self, tick: int) -> list[dict]:
        """The fault injections sent at ``tick``, as ``injected`` lists them."""
        return [{"tick": tick, "target": t, "value": v} for t, v in self.faults.get(tick, ())]

    def demand_ticks(self) -> range:
        """The ticks the command node sends frames at in lockstep, in order: the first below the
        lead from ``start``, the rest on the sensor frames."""
        return range(0, self.last_tick + 1, self.every)

    def start(self, send: SendFn) -> None:
        if self.realtime:
            return  # real time: demands go out by the node's own clock (on_period)
        for tick in range(0, min(self.lead, self.last_tick + 1), self.every):
            self._play(tick, send)
            self.next_play = tick + self.every

    def on_frame(
        self, frame_id: int, data: bytes | bytearray, send: SendFn, wall_s: float | None = None
    ) -> None:
        recorder = self.recorder
        tick_before = recorder.tick
        self._wall_s = wall_s
        recorder.record(frame_id, data, wall_s)
        if frame_id == SENSORS and not self.realtime:
            # every demand tick up to the lead: one at a time, or those after a sensor frame
            # the bus lost for this node (the ECU would wait for them for ever)
            target = min(recorder.latest_sensor_tick + self.lead, self.last_tick)
            while self.next_play <= target:
                self._play(self.next_play, send)
                self.next_play += self.every
            recorder.commands_sent()
        if recorder.tick != tick_before:  # the ECU answered a tick
            if self.progress is not None:
                self.progress(recorder.tick)
            if recorder.tick > self.last_tick:
                self.finished = True

    def on_timeout(self, send: SendFn) -> None:
        pass

    def on_period(self, send: SendFn, wall_s: float | None = None) -> None:
        """Real time: the demand (and faults) due at this period of the node's own clock."""
        tick = self.own_tick
        self._wall_s = wall_s
        if tick > self.last_tick + self.lead:  # the ECU stopped answering: give up
            self.finished = True
            return
        if tick <= self.last_tick and tick % self.every == 0:
            self._play(tick, send)
        self.own_tick = tick + 1
