"""Messages: a fixed header and a msgpack body, one message per frame.

Header (big-endian, 6 bytes): protocol version (u8), kind (u8: request, response, stream), sequence
number (u16), service (u8), status (u8: 0 in requests and stream samples). A response carries
the sequence number and service of its request; stream samples count their own sequence. The
body is msgpack (a map, a list or nil); an error response's body is ``{"error": text}``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import msgpack

from ecu.service.crc import crc16
from ecu.service.framing import MAX_PAYLOAD

VERSION = 1
HEADER = struct.Struct(">BBHBB")


class Kind(IntEnum):
    REQUEST = 1
    RESPONSE = 2
    STREAM = 3


class Service(IntEnum):
    IDENTIFY = 0x01  # -> firmware, build, protocol, parameter-set CRC, storage, counters
    STREAM = 0x02  # {"rate_hz": r} (0 stops) -> {"rate_hz", "every", "fields"}; samples follow
    COUNTERS = 0x03  # -> [frame and request counters, service time per tick] (port.COUNTER_NAMES)
    PARAM_INFO = 0x10  # {"index": i} -> one parameter's name, Q format, unit, limits, value
    PARAM_READ = 0x11  # {"name": n} -> {"name", "raw", "frac_bits", "value"}
    PARAM_WRITE = 0x12  # {"name": n, "raw": q} -> same as read (needs the unlock)
    PARAM_SAVE = 0x13  # -> {"slot", "sequence", "crc"} once written to flash (needs the unlock)
    FAULT_LOG_READ = 0x20  # {"start": i} -> {"total", "entries": [...]}
    FAULT_LOG_CLEAR = 0x21  # -> {"cleared": n}
    LOGBOOK_READ = 0x22  # -> [the engine's logbook] (ecu.logbook.word_names order)
    UNLOCK_SEED = 0x30  # -> {"seed": s}
    UNLOCK_KEY = 0x31  # {"key": k} -> {"unlocked": true, "timeout_s"}
    ARM = 0x40  # arm request (needs the unlock)
    STOP = 0x41  # stop request, latched until ARM; always allowed
    THROTTLE = 0x42  # {"pct": x} -> the bench's speed demand, %N (needs the unlock)


class Status(IntEnum):
    OK = 0
    BAD_VERSION = 1
    UNKNOWN_SERVICE = 2
    BAD_REQUEST = 3  # body malformed or a field missing or of the wrong type
    LOCKED = 4  # the service needs the unlock step first
    OUT_OF_RANGE = 5  # value outside the parameter's limits
    REFUSED_IN_RUN = 6  # parameter unsafe to change while the engine runs
    UNKNOWN_PARAM = 7
    INVALID = 8  # the parameter set as a whole is refused (ecu.params.validate)
    BAD_KEY = 9
    BUSY = 10  # a flash write is in progress
    STORAGE = 11  # no flash image, or it cannot be read or written
    REFUSED = 12  # the ECU's state does not allow it now (the answer says why)


UNLOCK_SECRET = b"turbojet-sil service"


def unlock_key(seed: int) -> int:
    """The key that answers an unlock seed (a guard against accidental writes, not security)."""
    return crc16(seed.to_bytes(4, "big") + UNLOCK_SECRET)


class MessageError(ValueError):
    """A payload that is not a message of this protocol."""


@dataclass(frozen=True)
class Message:
    kind: Kind
    seq: int
    service: int
    status: int = Status.OK
    body: Any = None
    version: int = VERSION


def pack(msg: Message) -> bytes:
    payload = HEADER.pack(msg.version, msg.kind, msg.seq, msg.service, msg.status) + msgpack.packb(
        msg.body
    )
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(
            f"service 0x{msg.service:02X}: message of {len(payload)} bytes exceeds {MAX_PAYLOAD}"
        )
    return payload


def unpack(payload: bytes) -> Message:
    """Parse a frame's payload; :class:`MessageError` says what is wrong with it."""
    if len(payload) < HEADER.size:
        raise MessageError(f"message of {len(payload)} bytes is shorter than its header")
    version, kind, seq, service, status = HEADER.unpack_from(payload)
    if kind not in Kind._value2member_map_:
        raise MessageError(f"unknown message kind {kind}")
    body: Any = None
    if version == VERSION:
        try:
            body = msgpack.unpackb(payload[HEADER.size :])
        except (ValueError, TypeError, msgpack.UnpackException) as exc:
            raise MessageError(f"body is not msgpack: {exc}") from None
    return Message(Kind(kind), seq, service, status, body, version)
