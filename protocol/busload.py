"""Bus load of classical CAN: exact frame length in bits, stuff bits included.

A base-format data frame is SOF, 11-bit ID, RTR, IDE, r0, 4-bit DLC, the data and a 15-bit CRC,
all subject to bit stuffing (a complement bit after five equal bits; the stuff bit counts towards
the next run), followed by 13 unstuffed bits: CRC delimiter, ACK slot, ACK delimiter, 7-bit end of
frame and 3-bit intermission.
"""

from __future__ import annotations

DEFAULT_BITRATE = 500_000
CRC15_POLY = 0x4599  # ISO 11898-1: x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1
_UNSTUFFED_TAIL_BITS = 13
_HEADER_BITS = 19  # SOF, ID, RTR, IDE, r0, DLC


def _crc15_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ CRC15_POLY) if crc & 0x4000 else (crc << 1)
            crc &= 0x7FFF
        table.append(crc)
    return tuple(table)


_CRC15_TABLE = _crc15_table()


def crc15(data: bytes) -> int:
    """CRC-15/CAN of whole bytes (leading zero bits do not change it: pad on the left)."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15_TABLE[((crc >> 7) ^ byte) & 0xFF]
    return crc


def _stuff_step(state: int, bit: int) -> tuple[int, int]:
    """One bit through the stuffing rule; state = last bit * 8 + run length (0: no bit yet)."""
    last, run = divmod(state, 8)
    run = run + 1 if run and bit == last else 1
    if run == 5:  # a complement bit goes in and starts the next run
        return 1, (1 - bit) * 8 + 1
    return 0, bit * 8 + run


def _stuff_table() -> tuple[int, ...]:
    """For every state and byte: stuff bits inserted * 16 + the state after the byte."""
    table = [0] * (16 * 256)
    for state in range(16):
        for byte in range(256):
            count, s = 0, state
            for i in range(7, -1, -1):
                inserted, s = _stuff_step(s, (byte >> i) & 1)
                count += inserted
            table[state * 256 + byte] = count * 16 + s
    return tuple(table)


_STUFF_TABLE = _stuff_table()


def stuff_bits(value: int, nbits: int) -> int:
    """Stuff bits a CAN controller inserts into the ``nbits``-bit string ``value`` (MSB first)."""
    whole, tail = divmod(nbits, 8)
    count, state = 0, 0
    for byte in (value >> tail).to_bytes(whole, "big"):
        entry = _STUFF_TABLE[state * 256 + byte]
        count += entry >> 4
        state = entry & 15
    for i in range(tail - 1, -1, -1):
        inserted, state = _stuff_step(state, (value >> i) & 1)
        count += inserted
    return count


def frame_bits(arbitration_id: int, data: bytes | bytearray) -> int:
    """Length on the wire of a base-format (11-bit ID) classical CAN data frame."""
    if not 0 <= arbitration_id < 0x800:
        raise ValueError(f"ID 0x{arbitration_id:X} is not an 11-bit identifier")
    n = len(data)
    if n > 8:
        raise ValueError(f"{n} data bytes: classical CAN carries at most 8")
    # SOF (0), ID, RTR/IDE/r0 (0), DLC: the leading 0 of SOF is implicit in the integer
    body = (((arbitration_id << 7) | n) << (8 * n)) | int.from_bytes(data, "big")
    nbits = _HEADER_BITS + 8 * n
    crc = crc15(body.to_bytes((nbits + 7) // 8, "big"))
    return nbits + 15 + stuff_bits((body << 15) | crc, nbits + 15) + _UNSTUFFED_TAIL_BITS


def bus_load_pct(total_bits: int, seconds: float, bitrate: int = DEFAULT_BITRATE) -> float:
    """Percent of the bus's capacity used by ``total_bits`` over ``seconds``."""
    if seconds <= 0:
        return 0.0
    return 100.0 * total_bits / (bitrate * seconds)
