"""The plant's frames packed by one compiled call, from a plant's state array (plant/periphery.py).

PlantTruthA/B/C, PlantAnalog and PlantSensors of a tick with the codec's layout, saturation,
alive counters and E2E CRC: the bytes the codec's ``pack_raw`` gives (``pack_plant_frames``,
the layout array from ``frame_layout``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from plant import flags as fl
from plant.jit import EXACT
from plant.periphery import OUT
from protocol.codec import MessageCodec
from protocol.e2e import COUNTER_MODULO, crc8

# messages in the order they go out at a tick; their payloads are 8 bytes each of one buffer
FRAMES = ("PlantTruthA", "PlantTruthB", "PlantTruthC", "PlantAnalog", "PlantSensors")
DUE_TRUTH, DUE_ANALOG = 1, 2
MAX_FIELDS = 8
# the int64 layout array: the CRC-8 table, then per message its alive counter, the CRC register
# after its data ID, its number of fields and (start, mask, raw_min, raw_max) per field
CRC_TABLE = 0
MESSAGE = 256
MESSAGE_SLOTS = 3 + 4 * MAX_FIELDS
COUNTER, CRC_START, N_FIELDS, FIELDS = range(4)
_O_TIME, _O_SPEED, _O_EGT, _O_SUPPLY, _O_CURRENT, _O_N_RPM = range(OUT, OUT + 6)
_O_P3, _O_P5, _O_T4, _O_FUEL, _O_THRUST = OUT + 7, OUT + 8, OUT + 9, OUT + 11, OUT + 13
_O_STARTER_A, _O_METAL, _O_UNBURNT, _O_BURNING = range(OUT + 16, OUT + 20)
_CLAMPED = fl.COMPRESSOR_MAP_CLAMPED | fl.TURBINE_MAP_CLAMPED | fl.PUMP_MAP_CLAMPED


def frame_layout(messages: list[MessageCodec]) -> np.ndarray:
    """The int64 layout array of ``pack_plant_frames`` for these messages (counters as now)."""
    lay = np.zeros(MESSAGE + MESSAGE_SLOTS * len(messages), dtype=np.int64)
    lay[CRC_TABLE : CRC_TABLE + 256] = [crc8(bytes((i,)), 0) for i in range(256)]
    for k, m in enumerate(messages):
        if not m.protected or m.multiplexed or len(m._fields) > MAX_FIELDS:
            raise ValueError(f"{m.name}: not a plain E2E-protected message")
        b = MESSAGE + MESSAGE_SLOTS * k
        lay[b + COUNTER], lay[b + CRC_START], lay[b + N_FIELDS] = (
            m.counter,
            m._crc_start,
            len(m._fields),
        )
        for i, (start, mask, _sign, raw_min, raw_max) in enumerate(m._fields):
            lay[b + FIELDS + 4 * i : b + FIELDS + 4 * i + 4] = (start, mask, raw_min, raw_max)
    return lay


@njit(**EXACT, inline="always")
def _field(lay: np.ndarray, b: int, i: int, raw: int) -> int:
    """One raw value saturated to its range and shifted into place (MessageCodec.pack_raw)."""
    f = b + FIELDS + 4 * i
    if raw < lay[f + 2]:
        raw = lay[f + 2]
    elif raw > lay[f + 3]:
        raw = lay[f + 3]
    return (raw & lay[f + 1]) << lay[f]


@njit(**EXACT, inline="always")
def _rounded(lay: np.ndarray, b: int, i: int, value: float) -> int:
    """round(value) (half to even) saturated to field i's range, shifted into place."""
    f = b + FIELDS + 4 * i
    r = np.rint(value)
    if r < lay[f + 2]:
        raw = lay[f + 2]
    elif r > lay[f + 3]:
        raw = lay[f + 3]
    else:
        raw = int(r)
    return (raw & lay[f + 1]) << lay[f]


@njit(**EXACT, inline="always")
def _finish(lay: np.ndarray, k: int, word: int, buf: np.ndarray) -> None:
    """Alive counter, little-endian bytes and CRC of message k into buf[8k:8k+8]."""
    b = MESSAGE + MESSAGE_SLOTS * k
    counter = lay[b + COUNTER]
    word |= counter << 8
    lay[b + COUNTER] = counter + 1 if counter < COUNTER_MODULO - 1 else 0
    at = 8 * k
    crc = lay[b + CRC_START]
    for i in range(1, 8):
        byte = (word >> (8 * i)) & 0xFF
        buf[at + i] = byte
        crc = lay[CRC_TABLE + (crc ^ byte)]
    buf[at] = crc


@njit(**EXACT)
def pack_plant_frames(
    s: np.ndarray, lay: np.ndarray, buf: np.ndarray, flags: int, tick16: int, due: int
) -> None:
    """Pack the frames due at this tick (FRAMES order; PlantSensors always) from the plant's
    outputs in its state array s, as PlantNode packs them through the codec."""
    if due & DUE_TRUTH:
        b = MESSAGE
        word = _field(lay, b, 0, 1 if flags & fl.FLAMEOUT else 0)
        word |= _field(lay, b, 1, 1 if flags & _CLAMPED else 0)
        word |= _field(lay, b, 2, 1 if flags & fl.OVERSPEED else 0)
        word |= _field(lay, b, 3, 1 if flags & fl.OVERTEMPERATURE else 0)
        word |= _rounded(lay, b, 4, s[_O_P3] * 0.1)
        word |= _rounded(lay, b, 5, s[_O_P5] * 0.1)
        word |= _rounded(lay, b, 6, s[_O_T4] * 10.0)
        _finish(lay, 0, word, buf)
        b = MESSAGE + MESSAGE_SLOTS
        word = _rounded(lay, b, 0, s[_O_FUEL] * 1e6)
        word |= _rounded(lay, b, 1, s[_O_THRUST] * 20.0)
        word |= _rounded(lay, b, 2, s[_O_N_RPM])
        _finish(lay, 1, word, buf)
        b = MESSAGE + 2 * MESSAGE_SLOTS
        word = _field(lay, b, 0, 1 if s[_O_BURNING] != 0.0 else 0)
        word |= _rounded(lay, b, 1, s[_O_METAL] * 10.0)
        word |= _rounded(lay, b, 2, s[_O_STARTER_A] * 20.0)
        word |= _rounded(lay, b, 3, s[_O_UNBURNT] * 1e6)
        _finish(lay, 2, word, buf)
    if due & DUE_ANALOG:
        b = MESSAGE + 3 * MESSAGE_SLOTS
        word = _field(lay, b, 0, tick16)
        word |= _rounded(lay, b, 1, s[_O_SUPPLY] * 1000.0)
        word |= _rounded(lay, b, 2, s[_O_CURRENT] * 1000.0)
        _finish(lay, 3, word, buf)
    b = MESSAGE + 4 * MESSAGE_SLOTS
    word = _field(lay, b, 0, tick16)
    word |= _rounded(lay, b, 1, s[_O_SPEED])
    word |= _rounded(lay, b, 2, s[_O_EGT] * 10.0)
    _finish(lay, 4, word, buf)
