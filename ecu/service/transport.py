"""Non-blocking byte I/O for the service port: a serial device, a pseudo-terminal or a URL.

``open_transport(spec)`` takes

- ``pty``: a new pseudo-terminal; the ECU keeps the master side and :attr:`Transport.name` is the
  slave's path (``/dev/pts/N``) for the client to open as a serial port;
- a device path (``/dev/ttyUSB0``, or a pty slave): opened with pyserial (raw, 115200 baud);
- a pyserial URL (``loop://``, ``socket://HOST:PORT``, ``rfc2217://HOST:PORT``).

Reads never wait and return at most the bytes asked for; writes return how many bytes the line
took (possibly none), so the ECU never blocks on a slow or absent client. Ports with a file
descriptor (devices, ptys) are read and written on the descriptor directly, non-blocking;
URL ports go through pyserial: ``loop://`` is written no further than its 4096-byte queue has
room, the others wait at most 2 ms.
"""

from __future__ import annotations

import os
import tty
from typing import Protocol

import serial


class TransportError(OSError):
    """The port cannot be opened; the message names it."""


class Transport(Protocol):
    name: str

    def read(self, max_bytes: int) -> bytes: ...

    def write(self, data: bytes) -> int: ...

    def close(self) -> None: ...


class FdTransport:
    """A file descriptor in non-blocking mode (pty master, or a pyserial port's descriptor)."""

    def __init__(self, fd: int, name: str, keep: object = None) -> None:
        os.set_blocking(fd, False)
        self.fd = fd
        self.name = name
        self._keep = keep  # what owns the descriptor (a pyserial port), closed with it
        self._slave_fd: int | None = None

    def read(self, max_bytes: int) -> bytes:
        try:
            return os.read(self.fd, max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO: a pty whose other side is closed
            return b""

    def write(self, data: bytes) -> int:
        try:
            return os.write(self.fd, data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            return 0

    def close(self) -> None:
        if self._keep is not None:
            self._keep.close()
        else:
            os.close(self.fd)
        if self._slave_fd is not None:
            os.close(self._slave_fd)


class SerialTransport:
    """A pyserial port without a descriptor (URL handlers)."""

    def __init__(self, port: serial.SerialBase, name: str) -> None:
        self.port = port
        self.name = name

    def read(self, max_bytes: int) -> bytes:
        try:
            n = min(self.port.in_waiting, max_bytes)
            return self.port.read(n) if n else b""
        except (serial.SerialException, OSError):  # a lost connection reads as silence
            return b""

    def write(self, data: bytes) -> int:
        try:
            capacity = getattr(self.port, "buffer_size", None)  # loop://: a bounded queue
            if capacity is not None:
                data = data[: max(0, capacity - self.port.out_waiting)]
                if not data:
                    return 0
            return self.port.write(data) or 0
        except (serial.SerialException, OSError):  # timed out or disconnected: not taken
            return 0

    def close(self) -> None:
        self.port.close()


def open_pty() -> FdTransport:
    master, slave = os.openpty()
    tty.setraw(slave)
    transport = FdTransport(master, os.ttyname(slave))
    transport._slave_fd = slave  # held open: no EIO while no client is attached
    return transport


def open_transport(spec: str) -> Transport:
    """Open the ECU side of the service port (see the module docstring)."""
    if spec == "pty":
        return open_pty()
    try:
        if "://" in spec:
            # URL handlers: writes wait at most 2 ms (loop:// has no such wait: it is in-process)
            timeout = None if spec.startswith("loop://") else 0.002
            port = serial.serial_for_url(spec, baudrate=115200, timeout=0, write_timeout=timeout)
            return SerialTransport(port, spec)
        port = serial.Serial(spec, baudrate=115200, timeout=0, write_timeout=0)
    except (serial.SerialException, ValueError) as exc:
        raise TransportError(f"port {spec!r}: cannot open it: {exc}") from None
    return FdTransport(port.fd, spec, keep=port)
