"""The device side of the slcan (Lawicel) serial protocol on a pseudo-terminal: a node behind it
looks to the host like a USB-CAN adapter, as a microcontroller's UART would (python-can's
``slcan`` interface, or any slcan tool, opens the terminal).

Bus spec ``slcan-device:PATH``: a new pseudo-terminal whose slave end is linked at PATH for the
host to open (``slcan:PATH``). Lines end in CR. From the host: ``tIIILDD..``/``TIIIIIIIILDD..``
(a frame to the node), ``rIIIL``/``RIIIIIIIIL`` (remote frames, counted and dropped), ``O``,
``L``, ``C``, ``Sn``, ``sXXYY``, ``V``, ``N``, ``F``, ``Z``, ``M``, ``m`` (answered with CR, or
the version and serial number for ``V`` and ``N``); anything else is answered with BEL and
counted. To the host: the node's frames as ``t``/``T`` lines. Frames from the host are taken
whether or not the channel was opened with ``O`` (a node has no use for a closed bus).
"""

from __future__ import annotations

import os
import select
import time
import tty
from pathlib import Path

import can

CR = b"\r"
BEL = b"\a"
VERSION = b"V0101\r"
SERIAL = b"NSIL1\r"
COMMANDS_OK = frozenset("OLCSsFZMmXWQU")
MAX_LINE = 64


class SlcanError(ValueError):
    """A line that is no slcan frame; the message names it."""


def encode(msg: can.Message) -> bytes:
    """The slcan line of a classical data frame."""
    data = bytes(msg.data)
    if msg.is_extended_id:
        head = f"T{msg.arbitration_id:08X}{len(data)}"
    else:
        head = f"t{msg.arbitration_id:03X}{len(data)}"
    return (head + data.hex().upper()).encode() + CR


def decode(line: bytes) -> can.Message:
    """The frame of a ``t``/``T`` line (without its CR)."""
    text = line.decode("ascii", "replace")
    extended = text[:1] == "T"
    width = 8 if extended else 3
    try:
        frame_id = int(text[1 : 1 + width], 16)
        dlc = int(text[1 + width], 16)
        data = bytes.fromhex(text[2 + width :])
    except (ValueError, IndexError):
        raise SlcanError(f"not an slcan frame: {text!r}") from None
    if dlc > 8 or len(data) != dlc or frame_id >= (1 << (29 if extended else 11)):
        raise SlcanError(f"not an slcan frame: {text!r}")
    return can.Message(arbitration_id=frame_id, is_extended_id=extended, data=data)


class SlcanDeviceBus(can.BusABC):
    """A python-can bus whose other end is a host speaking slcan on a pseudo-terminal."""

    def __init__(self, channel: str, **kwargs: object) -> None:
        self.link = Path(channel)
        self._master, slave = os.openpty()
        slave_path = os.ttyname(slave)
        tty.setraw(slave)  # bytes as they are, no echo, whatever the host sets
        os.close(slave)  # the host opens it by name; the master sees EIO until it does
        self.link.unlink(missing_ok=True)
        self.link.symlink_to(slave_path)
        self._buffer = bytearray()
        self._pending: list[can.Message] = []
        self.bad_lines = 0
        self.remote_frames = 0
        self.channel_info = f"slcan device on {slave_path} (linked at {self.link})"
        super().__init__(channel, **kwargs)

    def _answer(self, reply: bytes) -> None:
        os.write(self._master, reply)

    def _line(self, line: bytes) -> None:
        if not line:
            return
        kind = chr(line[0])
        if kind in "tT":
            try:
                self._pending.append(decode(line))
            except SlcanError:
                self.bad_lines += 1
                self._answer(BEL)
        elif kind in "rR":
            self.remote_frames += 1
        elif kind == "V":
            self._answer(VERSION)
        elif kind == "N":
            self._answer(SERIAL)
        elif kind in COMMANDS_OK:
            self._answer(CR)
        else:
            self.bad_lines += 1
            self._answer(BEL)

    def _read_available(self, timeout: float | None) -> None:
        ready, _, _ = select.select([self._master], [], [], timeout)
        if not ready:
            return
        try:
            chunk = os.read(self._master, 4096)
        except OSError:  # EIO: no host has the terminal open (yet)
            if timeout:
                time.sleep(min(timeout, 0.01))
            return
        self._buffer += chunk
        while (end := self._buffer.find(CR)) >= 0:
            line = bytes(self._buffer[:end]).strip(b"\n")
            del self._buffer[: end + 1]
            self._line(line)
        if len(self._buffer) > MAX_LINE:  # no CR in sight: garbage
            self.bad_lines += 1
            self._buffer.clear()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._pending:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            self._read_available(left)
            if not self._pending and deadline is not None and time.monotonic() >= deadline:
                return None, False
        return self._pending.pop(0), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_remote_frame or msg.is_error_frame or msg.is_fd:
            raise can.CanOperationError("slcan device: only classical data frames")
        os.write(self._master, encode(msg))

    def shutdown(self) -> None:
        super().shutdown()
        try:
            os.close(self._master)
        except OSError:
            pass
        self.link.unlink(missing_ok=True)
