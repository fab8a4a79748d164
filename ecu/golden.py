"""Golden vectors: the Python firmware's every tick (inputs, outputs, digest of the whole state),
for the C port to replay and match integer for integer. What they are recorded from (SIL
scenarios in process, a scripted sequence through every mode) is in :mod:`sil.run.golden`, which
runs the plant: the firmware side knows only the format and the recording tick.

File layout (``.gv``, little-endian int32 words, read by ``ecu/port/replay.c``): ``EGV1``, the
counts of parameter, input and output words and of ticks, the parameter words, then per tick the
inputs, the outputs and the state digest (FNV-1a over the state words in ``EcuState`` order).
"""

from __future__ import annotations

import sys
from array import array
from dataclasses import dataclass
from pathlib import Path

from ecu.firmware import Ecu, EcuInputs, EcuOutputs
from ecu.firmware_params import FirmwareParams
from ecu.params import EcuParams
from ecu.port.core import param_words
from ecu.state import EcuState

MAGIC = 0x31564745  # "EGV1"
INPUT_FIELDS = EcuInputs.FIELDS
OUTPUT_FIELDS = EcuOutputs.FIELDS
ROW_WORDS = len(INPUT_FIELDS) + len(OUTPUT_FIELDS) + 1
_FNV_OFFSET = 2166136261
_FNV_PRIME = 16777619


class GoldenError(ValueError):
    """A golden-vector file that cannot be read (names the file and what is wrong)."""


@dataclass
class Golden:
    """Parameters and, per tick, inputs + outputs + state digest (ROW_WORDS int32 words)."""

    name: str
    params: FirmwareParams
    rows: array  # 'i', ticks * ROW_WORDS

    @property
    def ticks(self) -> int:
        return len(self.rows) // ROW_WORDS


def state_digest(s: EcuState) -> int:
    """FNV-1a (32-bit) over the state's int32 words, in slot order (arrays expanded)."""
    h = _FNV_OFFSET
    for name in EcuState.FIELDS:
        value = getattr(s, name)
        for w in value if isinstance(value, array) else (value,):
            h = ((h ^ (w & 0xFFFFFFFF)) * _FNV_PRIME) & 0xFFFFFFFF
    return h


def _signed(u: int) -> int:
    return u - (1 << 32) if u >= 1 << 31 else u


class RecordingEcu(Ecu):
    """The Python firmware, appending every tick's row to ``rows``."""

    def __init__(self, params: EcuParams | FirmwareParams | None = None) -> None:
        super().__init__(params)
        self.rows = array("i")

    def tick(self, i: EcuInputs) -> EcuOutputs:
        rows = self.rows
        rows.extend(getattr(i, name) for name in INPUT_FIELDS)
        o = super().tick(i)
        rows.extend(getattr(o, name) for name in OUTPUT_FIELDS)
        rows.append(_signed(state_digest(self.s)))
        return o


def write(g: Golden, path: Path) -> None:
    words = param_words(g.params)
    head = array("i", [MAGIC, len(words), len(INPUT_FIELDS), len(OUTPUT_FIELDS), g.ticks])
    data = head + array("i", words) + g.rows
    if sys.byteorder != "little":
        data.byteswap()
    path.write_bytes(data.tobytes())


def read_rows(path: Path) -> tuple[list[int], array]:
    """The parameter words and the tick rows of a ``.gv`` file."""
    data = array("i")
    raw = path.read_bytes()
    if len(raw) % 4:
        raise GoldenError(f"{path}: length {len(raw)} is not a whole number of int32 words")
    data.frombytes(raw)
    if sys.byteorder != "little":
        data.byteswap()
    if len(data) < 5 or data[0] != MAGIC:
        raise GoldenError(f"{path}: not a golden-vector file (no EGV1 header)")
    _, n_params, n_in, n_out, ticks = data[:5]
    if (n_in, n_out) != (len(INPUT_FIELDS), len(OUTPUT_FIELDS)):
        raise GoldenError(f"{path}: {n_in} input / {n_out} output words, expected "
                          f"{len(INPUT_FIELDS)} / {len(OUTPUT_FIELDS)}")  # fmt: skip
    if len(data) != 5 + n_params + ticks * ROW_WORDS:
        raise GoldenError(f"{path}: {len(data)} words, the header announces {ticks} ticks")
    return list(data[5 : 5 + n_params]), data[5 + n_params :]
