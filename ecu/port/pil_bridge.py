"""The bridge between a run's bus and the firmware image's CAN link (``sil ecu --impl pil``).

Frames of the ECU's IDs (PlantSensors, PlantAnalog, Demand) go from the bus to the image, in the
order heard; every frame the image sends goes to the bus, in its order. The image keeps its own
clock: in lockstep it waits for its sensor frame (and a due Demand) as the Python and C nodes
do, so the bridge only carries frames and adds no timing of its own.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Collection

import can

from protocol.node import bus_batch_receiver

POLL_S = 0.05  # the longest either direction waits before it looks at the stop flag


class PilBridge:
    """Carry frames between ``bus`` (the run's) and ``image`` (the image's CAN link as a
    python-can bus, PilImage.open_bus) until ``should_stop()``; counts in :meth:`stats`."""

    def __init__(self, bus: can.BusABC, image: can.BusABC, frame_ids: Collection[int]) -> None:
        self.bus = bus
        self.image = image
        self.to_image = 0
        self.from_image = 0
        self.stale = 0  # frames the image sent before the bridge ran, dropped
        self.errors: list[str] = []
        bus.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in frame_ids])
        self._ids = frozenset(frame_ids)
        self._stop = threading.Event()

    def run(self, should_stop: Callable[[], bool]) -> None:
        while self.image.recv(0) is not None:  # sent before the run began (real time): not of it
            self.stale += 1
        back = threading.Thread(target=self._from_image, name="pil-from-image", daemon=True)
        back.start()
        try:
            self._to_image(should_stop)
        finally:
            self._stop.set()
            back.join(2.0)

    def _to_image(self, should_stop: Callable[[], bool]) -> None:
        receive = bus_batch_receiver(self.bus)
        while not should_stop() and not self._stop.is_set():
            for got in receive(POLL_S):
                if type(got) is tuple:
                    frame_id, data = got
                elif got.is_extended_id or got.is_remote_frame or got.is_error_frame:
                    continue
                else:
                    frame_id, data = got.arbitration_id, got.data
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
        return out
