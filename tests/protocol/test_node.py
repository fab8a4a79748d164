"""Node drivers: the same sans-IO nodes in one process and over a bus, lockstep and real time."""

import gc
import threading
import time

import can

from protocol.bus import open_bus
from protocol.node import FINAL_WAIT_S, SPIN_S, InProcessBus, run_lockstep, run_realtime


class Pinger:
    """Sends tick k, waits for the echo, sends k+1 (the plant's role in lockstep)."""

    def __init__(self, ticks: int) -> None:
        self.ticks, self.k, self.finished, self.timeouts, self.log = ticks, 0, False, 0, []

    def start(self, send):
        send(0x100, self.k.to_bytes(2, "little") + bytes(6))

    def on_frame(self, frame_id, data, send):
        if frame_id != 0x110:
            return
        echoed = int.from_bytes(data[:2], "little")
        self.log.append(echoed)
        self.k += 1
        if self.k >= self.ticks:
            self.finished = True
        else:
            send(0x100, self.k.to_bytes(2, "little") + bytes(6))

    def on_timeout(self, send):
        self.timeouts += 1
        self.finished = True

    def on_period(self, send):
        self.start(send)
        self.k += 1
        self.finished = self.k >= self.ticks


class Echo:
    """Answers each tick frame with one frame echoing it (the ECU's role in lockstep)."""

    def __init__(self) -> None:
        self.finished = False
        self.seen = []
        self.buffer = bytearray(8)

    def start(self, send):
        pass

    def on_frame(self, frame_id, data, send):
        if frame_id == 0x100:
            self.seen.append(int.from_bytes(data[:2], "little"))
            self.buffer[:2] = data[:2]
            send(0x110, self.buffer)  # a reused buffer: the driver must copy it

    def on_timeout(self, send):
        pass

    def on_period(self, send):
        pass


def test_inprocess_bus_is_deterministic_and_copies_buffers():
    tapped = []
    pinger, echo = Pinger(50), Echo()
    InProcessBus([pinger, echo], tap=lambda fid, data: tapped.append((fid, data))).run()
    assert pinger.log == list(range(50)) and echo.seen == list(range(50))
    assert len(tapped) == 100 and tapped[1] == (0x110, bytes(8))


def test_lockstep_over_a_bus_between_threads():
    with open_bus("virtual:node_test") as bus_a, open_bus("virtual:node_test") as bus_b:
        echo = Echo()
        stop = threading.Event()
        t = threading.Thread(
            target=run_lockstep,
            args=(echo, bus_b),
            kwargs={"guard_s": 0.05, "should_stop": stop.is_set},
        )
        t.start()
        pinger = Pinger(200)
        stats = run_lockstep(pinger, bus_a, guard_s=2.0)
        stop.set()
        t.join(5)
        assert pinger.log == list(range(200)) and stats.timeouts == 0
        assert stats.sent == 200 and stats.received == 200


def test_lockstep_guard_calls_on_timeout_and_unusable_frames_are_counted():
    with open_bus("virtual:node_timeout") as bus_a, open_bus("virtual:node_timeout") as bus_b:
        bus_b.send(can.Message(arbitration_id=0x1FFFFFFF, data=bytes(8), is_extended_id=True))
        bus_b.send(can.Message(arbitration_id=0x110, is_error_frame=True))
        pinger = Pinger(5)
        stats = run_lockstep(pinger, bus_a, guard_s=0.05)
        assert pinger.timeouts == 1
        assert stats.ignored == {"extended ID": 1, "error frame": 1}


def test_realtime_paces_by_the_clock():
    now = [0.0]

    class FakeBus:
        def recv(self, timeout):
            now[0] += timeout
            return None

        def send(self, msg):
            pass

    def sleep(seconds):
        assert 0.0 < seconds <= FINAL_WAIT_S + 1e-12  # only the last stretch is slept
        now[0] += seconds + SPIN_S  # and the spin after it ends at once

    pinger = Pinger(10)
    set_up = [object()]  # an object of the node's set-up, tracked by the collector
    gc.unfreeze()
    try:
        stats = run_realtime(pinger, FakeBus(), 0.01, clock=lambda: now[0], sleep=sleep)
        assert gc.get_freeze_count() > 0  # what existed when the loop began is frozen ...
        assert not any(o is set_up for o in gc.get_objects())  # ... out of the collector's reach
    finally:
        gc.unfreeze()
    assert stats.periods == 10 and stats.overruns == 0
    assert max(stats.jitter_s) < 1e-9


def test_a_node_naming_its_ids_hears_only_those():
    class Listener(Echo):
        frame_ids = (0x100,)

    with open_bus("virtual:node_ids") as bus_a, open_bus("virtual:node_ids") as bus_b:
        for frame_id in (0x300, 0x100, 0x110):
            bus_b.send(can.Message(arbitration_id=frame_id, data=bytes(8), is_extended_id=False))
        listener = Listener()
        stop = threading.Event()
        t = threading.Thread(target=lambda: (time.sleep(0.3), stop.set()))
        t.start()
        stats = run_lockstep(listener, bus_a, guard_s=0.05, should_stop=stop.is_set)
        t.join()
        assert listener.seen == [0] and stats.received == 1


def test_inprocess_bus_delivers_only_the_ids_a_node_names():
    class Listener(Echo):
        frame_ids = (0x200,)

    pinger, listener = Pinger(3), Listener()
    InProcessBus([pinger, Echo(), listener]).run()
    assert pinger.log == [0, 1, 2] and listener.seen == []  # 0x100 and 0x110 are not its IDs
