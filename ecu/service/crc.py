"""CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final XOR; check value 0x29B1
for b"123456789"), from crcmod's predefined table-driven implementation."""

from __future__ import annotations

import crcmod.predefined

crc16 = crcmod.predefined.mkCrcFun("crc-ccitt-false")
