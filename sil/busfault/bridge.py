"""The injector as a bridge between two python-can buses, in real time.

Every frame heard on one bus goes out on the other through the :class:`Injector`, so faults can
be put in front of a real ECU on an adapter (``socketcan:can0`` on one side, the SIL's bus on the
other). Time is counted in ECU periods from the bridge's start by the wall clock: a window and a
delay in ticks mean the same as in process. A python-can :class:`can.Notifier` reads each bus in
its own thread; one more thread releases delayed frames and sends a babbling node's frames. The
injector's decisions depend on the frames and their order, which on a real bus vary from run to
run; its random draws are seeded, as in process.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable

import can

from sil.busfault.injector import Injector


class Bridge:
    def __init__(
        self,
        a: can.BusABC,
        b: can.BusABC,
        injector: Injector,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.buses = (a, b)
        self.injector = injector
        self.period_s = 1.0 / injector.rate_hz
        self.clock = clock
        self.forwarded = [0, 0]  # frames sent onto a, onto b
        self._lock = threading.Lock()
        self._held: list[tuple[int, int, int, int, bytes]] = []  # (tick, seq, to, id, data)
        self._seq = 0
        self._t0 = 0.0
        self._stop = threading.Event()
        self._notifiers: list[can.Notifier] = []
        self._pump: threading.Thread | None = None

    def tick(self) -> int:
        return int((self.clock() - self._t0) / self.period_s)

    def start(self) -> None:
        self._t0 = self.clock()
        a, b = self.buses
        self._notifiers = [
            can.Notifier(a, [lambda m: self._heard(m, to=1)], timeout=0.05),
            can.Notifier(b, [lambda m: self._heard(m, to=0)], timeout=0.05),
        ]
        self._pump = threading.Thread(target=self._run_pump, name="busfault-bridge", daemon=True)
        self._pump.start()

    def stop(self) -> None:
        self._stop.set()
        for n in self._notifiers:
            n.stop()
        if self._pump is not None:
            self._pump.join()

    def __enter__(self) -> Bridge:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _heard(self, msg: can.Message, to: int) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_fd or msg.is_extended_id:
            return
        with self._lock:
            now = self.tick()
            for c in self.injector.transmit(now, msg.arbitration_id, bytes(msg.data)):
                if c.release_tick <= now:
                    self._send(to, msg.arbitration_id, c.data)
                else:
                    self._seq += 1
                    item = (c.release_tick, self._seq, to, msg.arbitration_id, c.data)
                    heapq.heappush(self._held, item)

    def _send(self, to: int, frame_id: int, data: bytes) -> None:
        msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)
        self.buses[to].send(msg)
        self.forwarded[to] += 1

    def _run_pump(self) -> None:
        """Each period: release the delayed frames due, send the babbling node's frames."""
        last = -1
        while not self._stop.is_set():
            with self._lock:
                now = self.tick()
                while self._held and self._held[0][0] <= now:
                    _, _, to, frame_id, data = heapq.heappop(self._held)
                    self._send(to, frame_id, data)
                for k in range(last + 1, now + 1):
                    for frame_id, data, _ in self.injector.flood(k):
                        self._send(0, frame_id, data)
                        self._send(1, frame_id, data)
                last = now
            due = self._t0 + (now + 1) * self.period_s
            self._stop.wait(max(0.0, due - self.clock()))
