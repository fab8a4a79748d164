"""The injector as a bridge between two python-can buses.

Every frame heard on one bus goes out on the other through the :class:`Injector`, so faults can
be put in front of a real ECU on an adapter (``socketcan:can0`` on one side, the SIL's bus on the
other; ``sil bridge``) or between the nodes of a ``sil run`` on a bus. A python-can
:class:`can.Notifier` reads each bus in its own thread.

Time is counted in ECU periods (ticks), as in process, by one of two clocks:

- :class:`WallTicks` (real time): periods of the wall clock since the bridge started. One more
  thread releases delayed frames and sends a babbling node's frames at each period.
- :class:`SensorTicks` (lockstep): the tick the plant's PlantSensors frames carry. The tick moves
  when the bridge hears PlantSensors(k); delayed frames due and the babbling node's frames for the
  new tick go out before it. With the lockstep order (one tick at a time, each node waiting for the
  other) the injector sees the same frames in the same order on every run, so a seeded run is
  repeatable, until a lost frame leaves a node to its wall-clock guard.

The injector's random draws are seeded, as in process.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable

import can

from protocol.lockstep import TICK_MODULO
from sil.busfault.injector import Injector

SENSORS_ID = 0x100  # PlantSensors; SensorTick in bytes 2-3, little-endian (protocol/turbojet.dbc)


class WallTicks:
    """Ticks of the wall clock: ECU periods since :meth:`start`."""

    paced = True  # the bridge's own thread runs the periods

    def __init__(self, rate_hz: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.period_s = 1.0 / rate_hz
        self.clock = clock
        self.t0 = 0.0

    def start(self) -> None:
        self.t0 = self.clock()

    def observe(self, frame_id: int, data: bytes) -> None:
        pass

    def now(self) -> int:
        return int((self.clock() - self.t0) / self.period_s)

    def until(self, tick: int) -> float:
        """Seconds until ``tick`` starts."""
        return self.t0 + tick * self.period_s - self.clock()


class SensorTicks:
    """The lockstep tick: SensorTick of the latest PlantSensors heard, unwrapped."""

    paced = False  # the frames move time

    def __init__(self) -> None:
        self.tick = 0

    def start(self) -> None:
        self.tick = 0

    def observe(self, frame_id: int, data: bytes) -> None:
        if frame_id == SENSORS_ID and len(data) >= 4:
            raw = data[2] | data[3] << 8
            delta = (raw - self.tick) % TICK_MODULO
            if delta < TICK_MODULO // 2:  # ahead or the same; an older tick does not move time
                self.tick += delta

    def now(self) -> int:
        return self.tick


class Bridge:
    def __init__(
        self,
        a: can.BusABC,
        b: can.BusABC,
        injector: Injector,
        *,
        ticks: WallTicks | SensorTicks | None = None,
    ) -> None:
        self.buses = (a, b)
        self.injector = injector
        self.ticks = ticks or WallTicks(injector.rate_hz)
        self.forwarded = [0, 0]  # frames sent onto a, onto b
        self.errors: list[str] = []  # sends that failed (a full queue, a bus gone)
        self._lock = threading.Lock()
        self._held: list[tuple[int, int, int, int, bytes]] = []  # (tick, seq, to, id, data)
        self._seq = 0
        self._last = -1  # the last tick whose babble went out
        self._stop = threading.Event()
        self._notifiers: list[can.Notifier] = []
        self.ecu_side_heard: dict[int, float] = {}  # frame ID -> time.monotonic() last heard
        self._pump: threading.Thread | None = None

    def start(self) -> None:
        self.ticks.start()
        a, b = self.buses
        self._notifiers = [
            can.Notifier(a, [lambda m: self._heard(m, to=1)], timeout=0.05),
            can.Notifier(b, [lambda m: self._heard(m, to=0)], timeout=0.05),
        ]
        if self.ticks.paced:
            self._pump = threading.Thread(
                target=self._run_pump, name="busfault-bridge", daemon=True
            )
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
        if to == 0:  # from the ECU's side: when its frames came, by ID, before the injector
            self.ecu_side_heard[msg.arbitration_id] = time.monotonic()
        if msg.is_error_frame or msg.is_remote_frame or msg.is_fd or msg.is_extended_id:
            return
        data = bytes(msg.data)
        with self._lock:
            self.ticks.observe(msg.arbitration_id, data)
            now = self.ticks.now()
            if not self.ticks.paced:
                self._due(now)
            for c in self.injector.transmit(now, msg.arbitration_id, data):
                if c.release_tick <= now:
                    self._send(to, msg.arbitration_id, c.data)
                else:
                    self._seq += 1
                    item = (c.release_tick, self._seq, to, msg.arbitration_id, c.data)
                    heapq.heappush(self._held, item)

    def _send(self, to: int, frame_id: int, data: bytes) -> None:
        msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)
        try:
            self.buses[to].send(msg)
        except can.CanError as exc:  # the bus is the fault's to report, not the bridge's end
            self.errors.append(f"0x{frame_id:03X} onto bus {'ab'[to]}: {exc}")
            return
        self.forwarded[to] += 1

    def _due(self, now: int) -> None:
        """Release the delayed frames due by ``now``, send the babbling node's frames of the
        ticks since the last call (caller holds the lock)."""
        while self._held and self._held[0][0] <= now:
            _, _, to, frame_id, data = heapq.heappop(self._held)
            self._send(to, frame_id, data)
        for k in range(self._last + 1, now + 1):
            for frame_id, data, _ in self.injector.flood(k):
                self._send(0, frame_id, data)
                self._send(1, frame_id, data)
        self._last = max(self._last, now)

    def _run_pump(self) -> None:
        ticks = self.ticks
        assert isinstance(ticks, WallTicks)
        while not self._stop.is_set():
            with self._lock:
                now = ticks.now()
                self._due(now)
            self._stop.wait(max(0.0, ticks.until(now + 1)))
