"""Seed and key of the XCP slave: the service port's unlock (:func:`ecu.service.message.unlock_key`)
as XCP's byte sequences.

GET_SEED gives a seed of 4 random bytes. The key is 2 bytes: the CRC-16/CCITT-FALSE (polynomial
0x1021, initial value 0xFFFF, no reflection, no final XOR) of the 4 seed bytes followed by the
ASCII secret ``turbojet-sil service``, most significant byte first. It is the same for every
resource (CAL/PAG, DAQ), as the service port's unlock is for every service: a guard against
accidental writes, not security. :func:`key_for` is what a master's seed-and-key function
computes (pyXCP: ``General.seed_n_key_function = lambda resource, seed: key_for(seed)``).
"""

from __future__ import annotations

from ecu.service.message import unlock_key

SEED_LENGTH = 4
KEY_LENGTH = 2


def key_for(seed: bytes) -> bytes:
    """The key that answers ``seed`` (4 bytes)."""
    return unlock_key(int.from_bytes(seed, "big")).to_bytes(KEY_LENGTH, "big")
