"""The bridge between a run's bus and the firmware image's CAN link (``sil ecu --impl pil``).

Frames of the ECU's IDs (PlantSensors, PlantAnalog, Demand) go from the bus to the image, in the
order heard; every frame the image sends goes to the bus, in its order. The image keeps its own
clock: in lockstep it waits for its sensor frame (and a due Demand) as the Python and C nodes
do, so the bridge only carries frames and adds no timing of its own.

Watched (a :class:`ecu.node.OtherEcuWatch`), the bridge hears the frames of the IDs the ECU sends
as another ECU's, as the Python and C nodes do: in real time it listens for them before the
image's engine frames reach the bus (those it sends meanwhile are dropped; XCP and the frames to
the image are carried), and an image that has not flown the engine for the watch's time when
another ECU is heard is silenced (nothing more of it reaches the bus) and the bridge ends; the
image's ticks are counted by its EcuActuator frames.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Collection

import can

from ecu.node import LISTEN_S, OtherEcuWatch
from protocol.node import bus_batch_receiver

POLL_S = 0.05  # the longest either direction waits before it looks at the stop flag


class PilBridge:
    """Carry frames between ``bus`` (the run's) and ``image`` (the image's CAN link as a
    python-can bus, PilImage.open_bus) until ``should_stop()``; counts in :meth:`stats`."""

    def __init__(
        self,
        bus: can.BusABC,
        image: can.BusABC,
        frame_ids: Collection[int],
        watch: OtherEcuWatch | None = None,
        actuator_id: int | None = None,
    ) -> None:
        self.bus = bus
        self.image = image
        self.to_image = 0
        self.from_image = 0
        self.stale = 0  # frames the image sent before the bridge ran, dropped
        self.image_ticks = 0  # the image's EcuActuator frames (one a tick)
        self.errors: list[str] = []
        self.watch = watch
        self._actuator_id = actuator_id
        heard = [*frame_ids, *(watch.names if watch is not None else ())]
        bus.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in heard])
        self._ids = frozenset(frame_ids)
        self._stop = threading.Event()
        self._listening = watch is not None and watch.listen_periods > 0

    @property
    def silenced(self) -> bool:
        return self.watch is not None and self.watch.refused is not None

    def run(self, should_stop: Callable[[], bool]) -> None:
        while self.image.recv(0) is not None:  # sent before the run began (real time): not of it
            self.stale += 1
        back = threading.Thread(target=self._from_image, name="pil-from-image", daemon=True)
        back.start()
        try:
            if self._listening:  # real time, watched: the bus heard first (XCP carried on)
                end = time.monotonic() + LISTEN_S
                self._to_image(lambda: should_stop() or time.monotonic() > end)
                self._listening = False
            self._to_image(should_stop)
        finally:
            self._stop.set()
            back.join(2.0)

    def _to_image(self, should_stop: Callable[[], bool]) -> None:
        """The bus's frames of the ECU's IDs to the image; another ECU's frames to the watch."""
        receive = bus_batch_receiver(self.bus)
        watch = self.watch
        while not should_stop() and not self._stop.is_set() and not self.silenced:
            for got in receive(POLL_S):
                if type(got) is tuple:
                    frame_id, data = got
                elif got.is_extended_id or got.is_remote_frame or got.is_error_frame:
                    continue
                else:
                    frame_id, data = got.arbitration_id, got.data
                if watch is not None and frame_id in watch.names:
                    watch.heard(frame_id, self.image_ticks)
                    continue
                if frame_id not in self._ids:
                    continue
                msg = can.Message(arbitration_id=frame_id, is_extended_id=False, data=data)
                try:
                    self.image.send(msg)
                except can.CanError as exc:
                    self._fail(f"to the image: {exc}")
                    return
                self.to_image += 1

    def _from_image(self) -> None:
        send = getattr(self.bus, "send_frame", None)
        while not self._stop.is_set():
            try:
                msg = self.image.recv(POLL_S)
            except can.CanError as exc:
                self._fail(f"from the image: {exc}")
                return
            if msg is None:
                continue
            if self.silenced:
                continue  # (another ECU flies the engine: nothing of this one reaches the bus)
            if self._listening and msg.arbitration_id in self.watch.names:
                self.stale += 1  # (the image's engine frames while the bridge listens)
                continue
            if msg.arbitration_id == self._actuator_id:
                self.image_ticks += 1
            if send is not None:
                send(msg.arbitration_id, msg.data)
            else:
                self.bus.send(msg)
            self.from_image += 1

    def _fail(self, what: str) -> None:
        if not self._stop.is_set():
            self.errors.append(what)
        self._stop.set()

    def stats(self) -> dict:
        out = {
            "frames_to_image": self.to_image,
            "frames_from_image": self.from_image,
            "frames_before_the_run": self.stale,
        }
        if self.errors:
            out["bridge_errors"] = self.errors
        if self.watch is not None:
            out.update(self.watch.summary())
        return out
