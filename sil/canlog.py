"""CAN log files: candump ``-L`` format as can-utils writes it, plus python-can's ASC and BLF.

``(1.234567) vcan0 100#0011223344556677`` per frame; in lockstep the timestamps are simulated
time, so two runs of the same scenario and seed give byte-identical files.
"""

from __future__ import annotations

from pathlib import Path
from typing import TextIO

import can

EXTRA_FORMATS = ("asc", "blf")


class CandumpWriter:
    """Writes frames in candump -L format; flushes often so a killed run keeps what it had."""

    def __init__(self, path: Path, channel: str = "vcan0", flush_every: int = 256) -> None:
        self.path = path
        self.channel = channel
        self.flush_every = flush_every
        self.frames = 0
        self._file: TextIO = path.open("w", encoding="ascii", newline="\n")

    def write(self, timestamp_s: float, frame_id: int, data: bytes | bytearray) -> None:
        line = f"({timestamp_s:.6f}) {self.channel} {frame_id:03X}#{data.hex().upper()}\n"
        self._file.write(line)
        self.frames += 1
        if self.frames % self.flush_every == 0:
            self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def convert(candump_path: Path, fmt: str) -> Path:
    """Write a copy of a candump log as ASC or BLF with python-can's writers."""
    if fmt not in EXTRA_FORMATS:
        raise ValueError(f"log format '{fmt}' is not one of {', '.join(EXTRA_FORMATS)}")
    target = candump_path.with_suffix(f".{fmt}")
    with can.Logger(str(target)) as writer:
        for message in can.CanutilsLogReader(str(candump_path)):
            writer.on_message_received(message)
    return target
