"""Per-message pack and unpack functions for the codec's hot path, written at start-up.

:class:`protocol.codec.MessageCodec` describes each signal by a flat field (start bit, mask, sign
bit or 0, raw_min, raw_max). :func:`packer` and :func:`unpacker` turn a message's fields into the
source of one Python function with every constant written in, and compile it: the arithmetic of
a loop over the fields (saturation to the raw range with one flag bit per value, mask and shift,
the sign taken from the top bit), without the loop, the tuple unpacking and the calls per field.
A multiplexed message gets one function per multiplexer index behind a lookup on the index.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from functools import cache
from types import CodeType
from typing import Protocol

from protocol.e2e import COUNTER_MODULO, crc8

Field = tuple[int, int, int, int, int]  # start, mask, sign bit or 0, raw_min, raw_max
PackFn = Callable[[Sequence[int]], int]
UnpackFn = Callable[[bytes | bytearray | memoryview, list], None]
_WORD = struct.Struct("<Q")


class Packed(Protocol):
    """What the packer needs of the message: its name, transmit buffer and alive counter."""

    name: str
    data: bytearray
    counter: int


def packer(message: Packed, fields: Sequence[Field], crc_start: int | None) -> PackFn:
    """``pack_raw(raws) -> saturated bits`` into ``message.data``; with ``crc_start`` (E2E
    protected) it sets the next alive counter and the CRC too."""
    n = len(fields)
    names = [f"r{i}" for i in range(n)]
    lines = [
        "def pack_raw(raws):",
        f"    if len(raws) != {n}:",
        f'        raise ValueError(f"{{message.name}}: expected {n} values, got {{len(raws)}}")',
        f"    {', '.join(names)}, = raws",
        "    saturated = 0",
    ]
    terms = []
    for i, (start, mask, _sign_bit, raw_min, raw_max) in enumerate(fields):
        r = names[i]
        lines += [
            f"    if {r} < {raw_min}:",
            f"        {r} = {raw_min}",
            f"        saturated |= {1 << i}",
            f"    elif {r} > {raw_max}:",
            f"        {r} = {raw_max}",
            f"        saturated |= {1 << i}",
        ]
        terms.append(f"({r} & {mask}) << {start}")
    word = " | ".join(terms)
    if crc_start is None:
        lines.append(f"    pack_into(data, 0, {word})")
    else:
        lines += [
            "    counter = message.counter",
            f"    message.counter = counter + 1 if counter < {COUNTER_MODULO - 1} else 0",
            f"    pack_into(data, 0, {word} | counter << 8)",
            f"    data[0] = crc8(tail, {crc_start})",
        ]
    lines.append("    return saturated")
    namespace = {
        "message": message,
        "data": message.data,
        "tail": memoryview(message.data)[1:],
        "pack_into": _WORD.pack_into,
        "crc8": crc8,
    }
    return _compile(lines, "pack_raw", namespace)


def unpacker(fields: Sequence[Field]) -> UnpackFn:
    """``unpack_raw(data, out)``: the raw values of a frame into ``out``, in field order."""
    lines = ["def unpack_raw(data, out):", "    word = unpack_from(data, 0)[0]"]
    lines += _unpack_lines(fields, 0)
    return _compile(lines, "unpack_raw", {"unpack_from": _WORD.unpack_from})


def mux_packer(name: str, by_index: Mapping[int, PackFn]) -> PackFn:
    """``pack_raw`` of a multiplexed message: the packer of the index in ``raws[0]``."""

    def pack_raw(raws: Sequence[int]) -> int:
        pack = by_index.get(raws[0])
        if pack is None:
            raise ValueError(f"{name}: no signal for multiplexer index {raws[0]}")
        return pack(raws)

    return pack_raw


def mux_unpacker(name: str, mux: Field, by_index: Mapping[int, Sequence[Field]]) -> UnpackFn:
    """``unpack_raw`` of a multiplexed message: the multiplexer field, then the fields its
    index selects."""
    start, mask = mux[0], mux[1]
    rest = {}
    for index, fields in by_index.items():
        lines = ["def unpack_rest(word, out):", *_unpack_lines(fields, 1)]
        rest[index] = _compile(lines, "unpack_rest", {})
    unpack_from = _WORD.unpack_from

    def unpack_raw(data: bytes | bytearray | memoryview, out: list) -> None:
        word = unpack_from(data, 0)[0]
        index = word >> start & mask
        unpack_rest = rest.get(index)
        if unpack_rest is None:
            raise ValueError(f"{name}: no signal for multiplexer index {index}")
        out[0] = index
        unpack_rest(word, out)

    return unpack_raw


def _unpack_lines(fields: Sequence[Field], first: int) -> list[str]:
    """Lines setting out[first:] from ``word``, one field each."""
    lines = []
    for i, (start, mask, sign_bit, _raw_min, _raw_max) in enumerate(fields, first):
        if sign_bit:
            lines += [
                f"    r = word >> {start} & {mask}",
                f"    out[{i}] = r - ((r & {sign_bit}) << 1)",
            ]
        else:
            lines.append(f"    out[{i}] = word >> {start} & {mask}")
    return lines


def _compile(lines: list[str], name: str, namespace: dict) -> Callable:
    exec(_code("\n".join(lines) + "\n", f"<protocol.packers {name}>"), namespace)
    return namespace[name]


@cache
def _code(source: str, filename: str) -> CodeType:
    """The source compiled once per process: codecs built again (a campaign builds one per
    run) bind the same code to their own buffers and counters."""
    return compile(source, filename, "exec")
