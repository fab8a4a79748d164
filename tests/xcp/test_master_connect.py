"""pyXCP's CONNECT to a slave that is busy (a run still starting): the master sends CONNECT
every 0.2 s, and the slave, once free, answers all it held at once. The answers beyond the
first are dropped, so every later command gets its own answer (XCP answers carry no request
number: one stale answer would shift all that follow)."""

from __future__ import annotations

import threading
import time

import can

from ecu.firmware import Ecu
from ecu.params import EcuParams
from ecu.service.port import boot
from ecu.xcp.slave import XcpSlave
from sil.record.xcp_master import connect, master

IDS = (0x700, 0x701)


class BusySlave:
    """An ECU's XCP slave on a virtual bus, served every 10 ms once ``busy_s`` has passed."""

    def __init__(self, channel: str, busy_s: float) -> None:
        b = boot(EcuParams(), None)
        self.slave = XcpSlave(Ecu(b.table.firmware), b, seed=3)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.free_at = time.monotonic() + busy_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.01):
            if time.monotonic() < self.free_at:
                continue
            while (msg := self.bus.recv(0)) is not None:
                if msg.arbitration_id == IDS[0]:
                    self.slave.receive(bytes(msg.data))
            self.slave.serve(self._send)

    def _send(self, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=IDS[1], data=data, is_extended_id=False))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.bus.shutdown()


def _identifier_after_connect(busy_s: float) -> str:
    channel = f"busy-slave-{busy_s}-{time.monotonic_ns()}"
    slave = BusySlave(channel, busy_s)
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        with master(bus, IDS, None) as x:
            connect(x, 10.0)
            x.getCommModeInfo()
            identifier = x.identifier(0)
            status = x.getStatus()
            x.disconnect()
        assert status is not None
        return identifier
    finally:
        bus.shutdown()
        slave.close()


def test_a_busy_slaves_late_answers_to_connect_are_dropped():
    at_once = _identifier_after_connect(0.0)
    assert at_once.startswith("turbojet-ecu ")  # the ECU's own identification
    assert _identifier_after_connect(1.0) == at_once  # five CONNECTs held, answered together
