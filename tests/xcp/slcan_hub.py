"""One bus of three: the ECU behind its pseudo-terminal (spoken to as an slcan host, lines in
and out), the loopback bus (where the plant is) and a second pseudo-terminal speaking slcan
(where the master is, with python-can's slcan interface). Every frame from one goes to the
others.

    python tests/xcp/slcan_hub.py ECU_TTY MASTER_TTY GROUP PORT

Runs until SIGTERM, in a process of its own (three reading threads)."""

from __future__ import annotations

import os
import select
import signal
import sys
import threading
import tty

import can

from protocol.slcan_device import SlcanDeviceBus, SlcanError, decode, encode
from protocol.udp_loopback import LoopbackUdpMulticastBus


class EcuLine:
    """The slcan host end of the ECU's terminal: frames as ``t`` lines, read in chunks."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        os.write(self.fd, b"C\rS6\rO\r")  # close, 500 kbit/s, open: as a host sets up
        self.buffer = bytearray()
        self.lock = threading.Lock()

    def send(self, msg: can.Message) -> None:
        with self.lock:
            os.write(self.fd, encode(msg))

    def frames(self, timeout: float) -> list[can.Message]:
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return []
        self.buffer += os.read(self.fd, 65536)
        out = []
        while (end := self.buffer.find(b"\r")) >= 0:
            line = bytes(self.buffer[:end]).lstrip(b"\x07")
            del self.buffer[: end + 1]
            if line[:1] in (b"t", b"T"):
                try:
                    out.append(decode(line))
                except SlcanError:
                    pass
        return out


def main(ecu_tty: str, master_tty: str, group: str, port: str) -> None:
    ecu = EcuLine(ecu_tty)
    device = SlcanDeviceBus(master_tty)
    udp = LoopbackUdpMulticastBus(group, int(port))
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())

    def from_ecu() -> None:
        while not done.is_set():
            for msg in ecu.frames(0.05):
                device.send(msg)
                udp.send(msg)

    def to_ecu(source: can.BusABC) -> None:
        while not done.is_set():
            try:
                msg = source.recv(0.05)
            except can.CanError:
                continue
            if msg is not None and not msg.is_error_frame:
                ecu.send(msg)

    threads = [
        threading.Thread(target=from_ecu, daemon=True),
        threading.Thread(target=to_ecu, args=(device,), daemon=True),
        threading.Thread(target=to_ecu, args=(udp,), daemon=True),
    ]
    for t in threads:
        t.start()
    print("hub: ready", flush=True)
    done.wait()
    for t in threads:
        t.join(2)
    device.shutdown()
    udp.shutdown()
    os.close(ecu.fd)


if __name__ == "__main__":
    main(*sys.argv[1:5])
