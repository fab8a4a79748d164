"""The injector between the nodes of an in-process run (``sil run --mode inproc``).

Like :class:`protocol.node.InProcessBus`, frames are delivered in the order they were sent, but
every frame on its way to the ECU and the plant passes through the :class:`Injector`; the
command node (the recorder) hears what was sent. Time is the plant's tick. A delayed frame is
released once the plant reaches its release tick, a babbling node's frames come at each new tick.

In lockstep a lost frame stalls the loop (the plant waits for the ECU's answer, the ECU for the
plant's sensors). On a bus the nodes' wall-clock guards end the stall; here a stall ends the same
way, deterministically: the node whose awaited frame was lost runs on its own clock for one
period (``on_timeout``): the ECU when it has not yet answered the plant's tick, else the plant.

After a faulted copy reaches its receiver, the receiver's E2E verdict on it is logged with the
event (``e2e``), so a report can tell whether each corrupted frame was caught.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Callable

from ecu.node import EcuNode
from plant.node import PlantNode
from protocol.e2e import E2EChecker
from protocol.lockstep import TICK_MODULO
from protocol.node import Node, SendFn
from sil.busfault.injector import Injector

_NOBODY = -1  # origin of the babbling node's frames


class FaultyInProcessBus:
    def __init__(self, command: Node, ecu: EcuNode, plant: PlantNode, injector: Injector) -> None:
        self.command, self.ecu, self.plant, self.injector = command, ecu, plant, injector
        self.nodes: list[Node] = [command, ecu, plant]
        self._queue: deque[tuple[int, int, bytes]] = deque()
        self._held: list[tuple[int, int, int, int, bytes, dict | None]] = []  # a heap
        self._seq = 0
        self._senders = [self._sender(i) for i in range(3)]
        # the receiver's checker of each protected frame ID, for the E2E verdict of faulted copies
        self._checkers: dict[int, tuple[int, E2EChecker]] = {
            ecu.sensors.frame_id: (1, ecu.sensors_check),
            ecu.analog.frame_id: (1, ecu.analog_check),
            ecu.demand.frame_id: (1, ecu.demand_check),
            plant.actuator.frame_id: (2, plant.actuator_check),
            plant.fault.frame_id: (2, plant.fault_check),
        }
        self.stalls = {"ecu": 0, "plant": 0}

    def _sender(self, index: int) -> SendFn:
        def send(frame_id: int, data: bytes | bytearray) -> None:
            self._queue.append((index, frame_id, bytes(data)))

        return send

    def run(self, done: Callable[[], bool]) -> None:
        for node, send in zip(self.nodes, self._senders, strict=True):
            node.start(send)
        tick = self.plant.tick
        while not done():
            now = self.plant.tick
            if now != tick:
                tick = now
                for frame_id, data, event in self.injector.flood(now):
                    self._to_nodes(_NOBODY, frame_id, data, event)
            if self._held and self._held[0][0] <= now:
                _, _, origin, frame_id, data, event = heapq.heappop(self._held)
                self._to_nodes(origin, frame_id, data, event)
            elif self._queue:
                self._deliver(*self._queue.popleft())
            elif not self._stall():
                return

    def _deliver(self, origin: int, frame_id: int, data: bytes) -> None:
        if origin != 0:
            self.command.on_frame(frame_id, data, self._senders[0])
        now = self.plant.tick
        if self.injector.quiet(now):
            self._to_nodes(origin, frame_id, data, None)
            return
        for c in self.injector.transmit(now, frame_id, data):
            if c.release_tick <= now:
                self._to_nodes(origin, frame_id, c.data, c.event)
            else:
                self._seq += 1
                heapq.heappush(
                    self._held, (c.release_tick, self._seq, origin, frame_id, c.data, c.event)
                )

    def _to_nodes(self, origin: int, frame_id: int, data: bytes, event: dict | None) -> None:
        for i in (1, 2):
            if i != origin:
                self.nodes[i].on_frame(frame_id, data, self._senders[i])
        if event is not None:
            receiver = self._checkers.get(frame_id)
            if receiver is not None and receiver[0] != origin:
                event["e2e"] = receiver[1].status.name

    def _stall(self) -> bool:
        """Nothing in flight: the node whose awaited frame was lost runs one period on its own
        clock (the next frame of a reordered ID brings the held one along)."""
        ecu, plant = self.ecu, self.plant
        answered = ecu.ticks > 0 and not ecu.waiting and ecu.tick == plant.tick % TICK_MODULO
        if answered:
            if plant.finished:
                return False
            self.stalls["plant"] += 1
            plant.on_timeout(self._senders[2])
        else:
            if ecu.finished:
                return False
            self.stalls["ecu"] += 1
            ecu.on_timeout(self._senders[1])
        return True
