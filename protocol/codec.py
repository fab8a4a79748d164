"""A struct-based codec for the hot path, generated from the DBC at start-up.

Every message of ``turbojet.dbc`` (but the XCP transport's, whose payload is a raw XCP packet:
:func:`protocol.dbc.is_xcp`) becomes a :class:`MessageCodec` holding its signal layout (start
bit, length, sign, scale, offset and range, all read from the DBC) and a preallocated 8-byte
transmit buffer. Packing writes into that buffer, sets the alive counter and the E2E CRC, and
returns a bitmask of the signals that were out of range: they are saturated to the DBC range,
never wrapped. Unpacking fills a caller's preallocated list. After start-up no call keeps any new
object alive (a test proves there is no growth in allocated blocks), and the results agree bit for
bit with cantools over the whole range of every signal (hypothesis).

Values are given positionally in ``MessageCodec.signal_names`` order (the E2E CRC and counter are
not among them: the codec owns those). Multiplexed messages (EcuTelemetry) take
``(mux_index, value)``: the value is laid out as the signal that index selects.

    codec = Codec()
    sensors = codec["PlantSensors"]            # or codec.by_id[0x100]
    saturated = sensors.pack_raw((tick, rpm, egt_dK))
    bus.send(can.Message(arbitration_id=sensors.frame_id, data=sensors.data, is_extended_id=False))
    sensors.unpack_raw(frame.data, out)        # out: a list of len(sensors.signal_names)
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cantools.database.can import Database

from protocol.dbc import DBC_PATH, ContractError, is_xcp, load_database, message_attribute
from protocol.e2e import COUNTER_MODULO, E2EChecker, crc8, data_id_crc_start
from protocol.packers import PackFn, UnpackFn, mux_packer, mux_unpacker, packer, unpacker

_WORD = struct.Struct("<Q")


@dataclass(frozen=True)
class SignalLayout:
    """One signal's place in the 64-bit little-endian frame word, with its scaling and range."""

    name: str
    start: int
    length: int
    signed: bool
    scale: float
    offset: float
    minimum: float
    maximum: float
    raw_min: int
    raw_max: int
    unit: str

    @property
    def field(self) -> tuple[int, int, int, int, int]:
        """(start, mask, sign bit or 0, raw_min, raw_max): the flat form the hot path loops over."""
        sign_bit = 1 << (self.length - 1) if self.signed else 0
        return self.start, (1 << self.length) - 1, sign_bit, self.raw_min, self.raw_max

    def to_raw(self, value: float) -> int:
        """Physical value to raw, rounding as cantools does (Python's round)."""
        return round((value - self.offset) / self.scale)

    def to_physical(self, raw: int) -> float:
        return raw * self.scale + self.offset


def _layout(signal) -> SignalLayout:
    if signal.byte_order != "little_endian":
        raise ContractError(f"signal {signal.name}: only little-endian (Intel) signals are used")
    if signal.is_float or signal.scale <= 0:
        raise ContractError(f"signal {signal.name}: only integer signals with a positive scale")
    lo_bits = -(1 << (signal.length - 1)) if signal.is_signed else 0
    hi_bits = (1 << (signal.length - 1)) - 1 if signal.is_signed else (1 << signal.length) - 1
    scale, offset = float(signal.scale), float(signal.offset)
    minimum = signal.minimum if signal.minimum is not None else lo_bits * scale + offset
    maximum = signal.maximum if signal.maximum is not None else hi_bits * scale + offset
    raw_min = max(lo_bits, round((minimum - offset) / scale))
    raw_max = min(hi_bits, round((maximum - offset) / scale))
    # keep the raw range inside the physical range when rounding pushed it out
    if raw_min * scale + offset < minimum - abs(scale) * 1e-9:
        raw_min += 1
    if raw_max * scale + offset > maximum + abs(scale) * 1e-9:
        raw_max -= 1
    return SignalLayout(
        signal.name,
        signal.start,
        signal.length,
        signal.is_signed,
        scale,
        offset,
        float(minimum),
        float(maximum),
        raw_min,
        raw_max,
        signal.unit or "",
    )


class MessageCodec:
    """Layout, transmit buffer and alive counter of one message (one per sending node)."""

    def __init__(self, message) -> None:
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.length: int = message.length
        if self.length != 8:
            raise ContractError(f"message {self.name}: every frame of this contract has 8 bytes")
        self.cycle_time_ms: int = message.cycle_time or 0
        self.senders: tuple[str, ...] = tuple(message.senders)
        self.sim_only: bool = message_attribute(message, "SimulationOnly", "No") in (1, "Yes")
        self.data_id: int = int(message_attribute(message, "E2EDataID", 0))
        self.protected: bool = self.data_id != 0
        self._crc_start = data_id_crc_start(self.data_id) if self.protected else 0
        self.counter: int = 0
        self.data = bytearray(8)
        self._tail = memoryview(self.data)[1:]

        e2e_names = {f"{s.name}" for s in message.signals if s.name.endswith(("_CRC", "_Counter"))}
        if self.protected and len(e2e_names) != 2:
            raise ContractError(f"message {self.name}: E2E protected but lacks _CRC/_Counter")
        plain = [s for s in message.signals if s.name not in e2e_names]
        mux = [s for s in plain if s.is_multiplexer]
        self.multiplexed = bool(mux)
        if self.multiplexed:
            self.mux_layout = _layout(mux[0])
            self.mux_signals: dict[int, SignalLayout] = {}
            for s in plain:
                if s.multiplexer_ids:
                    for mux_id in s.multiplexer_ids:
                        self.mux_signals[mux_id] = _layout(s)
            self.signals: tuple[SignalLayout, ...] = (self.mux_layout,)
            self.signal_names: tuple[str, ...] = (self.mux_layout.name, "value")
        else:
            self.signals = tuple(_layout(s) for s in sorted(plain, key=lambda s: s.start))
            self.signal_names = tuple(s.name for s in self.signals)
        self._fields = tuple(s.field for s in self.signals)
        # pack_raw(raws) -> int: raw values (signal_names order) into ``data`` with the next
        # alive counter and the CRC; bit i of the result is set when value i was outside its
        # DBC range and saturated. unpack_raw(data, out): a received frame's raw values into
        # ``out``, in the same order. Both are written for this message (protocol.packers).
        crc_start = self._crc_start if self.protected else None
        self.pack_raw: PackFn
        self.unpack_raw: UnpackFn
        if self.multiplexed:
            mux_fields = {k: (self.mux_layout.field, v.field) for k, v in self.mux_signals.items()}
            by_index = {k: packer(self, f, crc_start) for k, f in mux_fields.items()}
            self.pack_raw = mux_packer(self.name, by_index)
            self.unpack_raw = mux_unpacker(
                self.name, self.mux_layout.field, {k: f[1:] for k, f in mux_fields.items()}
            )
        else:
            self.pack_raw = packer(self, self._fields, crc_start)
            self.unpack_raw = unpacker(self._fields)

    def _layouts(self, first_raw: int) -> Sequence[SignalLayout]:
        if not self.multiplexed:
            return self.signals
        layout = self.mux_signals.get(first_raw)
        if layout is None:
            raise ValueError(f"{self.name}: no signal for multiplexer index {first_raw}")
        return (self.mux_layout, layout)

    def pack(self, values: Sequence[float]) -> int:
        """As ``pack_raw`` with physical values (scaled, offset and rounded as cantools).

        A value counts as out of range when it is more than half a step outside the DBC range.
        """
        layouts = self._layouts(int(values[0]))
        if len(values) != len(layouts):
            raise ValueError(f"{self.name}: expected {len(layouts)} values, got {len(values)}")
        word = 0
        saturated = 0
        for i, layout in enumerate(layouts):
            value = values[i]
            if value != value:  # NaN
                raise ValueError(f"{self.name}.{layout.name}: value is NaN")
            scaled = (value - layout.offset) / layout.scale
            if scaled < layout.raw_min - 0.5:
                raw = layout.raw_min
                saturated |= 1 << i
            elif scaled > layout.raw_max + 0.5:
                raw = layout.raw_max
                saturated |= 1 << i
            else:
                raw = min(max(round(scaled), layout.raw_min), layout.raw_max)
            word |= (raw & ((1 << layout.length) - 1)) << layout.start
        self._finish(word)
        return saturated

    def _finish(self, word: int) -> None:
        if self.protected:
            word |= self.counter << 8
            self.counter = self.counter + 1 if self.counter < COUNTER_MODULO - 1 else 0
        _WORD.pack_into(self.data, 0, word)
        if self.protected:
            self.data[0] = crc8(self._tail, self._crc_start)

    def unpack(self, data: bytes | bytearray | memoryview, out: list) -> None:
        """Physical values of a received frame into ``out``."""
        self.unpack_raw(data, out)
        layouts = self._layouts(out[0])
        for i in range(len(layouts)):
            out[i] = layouts[i].to_physical(out[i])

    def checker(self, *, max_delta: int = 1, timeout_ticks: int = 10) -> E2EChecker:
        """A receiver-side E2E checker for this message."""
        if not self.protected:
            raise ContractError(f"message {self.name} carries no E2E protection")
        return E2EChecker(self.data_id, max_delta=max_delta, timeout_ticks=timeout_ticks)


class Codec:
    """All messages of the contract, by name and by frame ID (one instance per node)."""

    def __init__(self, dbc_path: str | Path = DBC_PATH, database: Database | None = None) -> None:
        """The codec of the DBC at ``dbc_path``, or of an already loaded ``database`` (read
        only: codecs built on one database share it, each with its own buffers and counters)."""
        self.database = database if database is not None else load_database(dbc_path)
        self.messages = tuple(MessageCodec(m) for m in self.database.messages if not is_xcp(m))
        self.by_name = {m.name: m for m in self.messages}
        self.by_id = {m.frame_id: m for m in self.messages}

    def __getitem__(self, name: str) -> MessageCodec:
        try:
            return self.by_name[name]
        except KeyError:
            raise KeyError(f"no message {name!r} in the CAN contract") from None
