"""Bus load of classical CAN: exact frame length in bits, stuff bits included.

A base-format data frame is SOF, 11-bit ID, RTR, IDE, r0, 4-bit DLC, the data and a 15-bit CRC,
all subject to bit stuffing (a complement bit after five equal bits), followed by 13 unstuffed
bits: CRC delimiter, ACK slot, ACK delimiter, 7-bit end of frame and 3-bit intermission.
"""

from __future__ import annotations

DEFAULT_BITRATE = 500_000
_UNSTUFFED_TAIL_BITS = 13
_CRC15_POLY = 0x4599


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def _crc15(bits: list[int]) -> int:
    crc = 0
    for bit in bits:
        feedback = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= _CRC15_POLY
    return crc


def _stuff_bits(bits: list[int]) -> int:
    count, run, last = 0, 0, -1
    for bit in bits:
        if bit == last:
            run += 1
        else:
            last, run = bit, 1
        if run == 5:
            count += 1
            last, run = 1 - bit, 1  # the stuff bit starts the next run
    return count


def frame_bits(arbitration_id: int, data: bytes | bytearray) -> int:
    """Length on the wire of a base-format (11-bit ID) classical CAN data frame."""
    if not 0 <= arbitration_id < 0x800:
        raise ValueError(f"ID 0x{arbitration_id:X} is not an 11-bit identifier")
    if len(data) > 8:
        raise ValueError(f"{len(data)} data bytes: classical CAN carries at most 8")
    body = [0] + _bits(arbitration_id, 11) + [0, 0, 0] + _bits(len(data), 4)
    for byte in data:
        body += _bits(byte, 8)
    body += _bits(_crc15(body), 15)
    return len(body) + _stuff_bits(body) + _UNSTUFFED_TAIL_BITS


def bus_load_pct(total_bits: int, seconds: float, bitrate: int = DEFAULT_BITRATE) -> float:
    """Percent of the bus's capacity used by ``total_bits`` over ``seconds``."""
    if seconds <= 0:
        return 0.0
    return 100.0 * total_bits / (bitrate * seconds)
