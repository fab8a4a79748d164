"""Protocol self-check: two endpoints on one bus exchange every message of the contract.

For each message a sender packs known values with the codec and sends them; a receiver decodes
them with the codec and with cantools and runs the E2E checker. Then the checker is shown a
corrupted, a repeated and a skipped frame, and a silence longer than its timeout.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import can

from protocol.bus import BusSpec, open_bus
from protocol.codec import Codec, MessageCodec
from protocol.e2e import E2EStatus


@dataclass
class CheckRow:
    message: str
    frame_id: int
    sent: dict[str, float]
    decoded_codec: dict[str, float]
    decoded_cantools: dict[str, float]
    e2e: str
    ok: bool


@dataclass
class SelfCheckReport:
    bus: str
    rows: list[CheckRow] = field(default_factory=list)
    e2e_cases: dict[str, str] = field(default_factory=dict)
    round_trip_us: float = 0.0

    @property
    def ok(self) -> bool:
        expected = {
            "corrupted": "WRONGCRC",
            "repeated": "REPEATED",
            "skipped": "WRONGSEQUENCE",
            "silence": "NONEWDATA",
        }
        return all(r.ok for r in self.rows) and self.e2e_cases == expected

    def as_dict(self) -> dict:
        return {
            "bus": self.bus,
            "ok": self.ok,
            "round_trip_us": self.round_trip_us,
            "messages": [asdict(r) for r in self.rows],
            "e2e_cases": self.e2e_cases,
        }


def _sample_values(message: MessageCodec) -> list[float]:
    """Mid-range values (a third of the way up each range), exact on the raw grid."""
    if message.multiplexed:
        layout = message.mux_signals[2]
        return [2.0, layout.to_physical((layout.raw_min + 2 * layout.raw_max) // 3)]
    return [s.to_physical((2 * s.raw_min + s.raw_max) // 3 + 1) for s in message.signals]


def _receive(bus: can.BusABC, frame_id: int, timeout_s: float = 2.0) -> can.Message:
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        msg = bus.recv(remaining)
        if msg is not None and msg.arbitration_id == frame_id:
            return msg
    raise TimeoutError(f"frame 0x{frame_id:03X} not received within {timeout_s} s")


def run_selfcheck(spec: BusSpec | str) -> SelfCheckReport:
    tx_codec, rx_codec = Codec(), Codec()
    report = SelfCheckReport(bus=str(spec))
    with open_bus(spec) as tx, open_bus(spec) as rx:
        trips = []
        for message in tx_codec.messages:
            values = _sample_values(message)
            message.pack(values)
            t0 = time.perf_counter()
            tx.send(
                can.Message(
                    arbitration_id=message.frame_id, data=message.data, is_extended_id=False
                )
            )
            received = _receive(rx, message.frame_id)
            trips.append(time.perf_counter() - t0)
            receiver = rx_codec.by_id[message.frame_id]
            out = [0.0] * len(values)
            receiver.unpack(received.data, out)
            names = receiver.signal_names
            if receiver.multiplexed:
                names = (names[0], receiver.mux_signals[int(out[0])].name)
            by_cantools = rx_codec.database.decode_message(
                message.frame_id, received.data, decode_choices=False
            )
            e2e = receiver.checker().check(received.data).name if receiver.protected else "-"
            sent = dict(zip(names, values, strict=True))
            mine = dict(zip(names, out, strict=True))
            theirs = {n: float(by_cantools[n]) for n in names}
            ok = (
                mine == sent
                and all(abs(theirs[n] - sent[n]) <= 1e-9 * max(1, abs(sent[n])) for n in names)
                and e2e in ("OK", "-")
            )
            report.rows.append(
                CheckRow(message.name, message.frame_id, sent, mine, theirs, e2e, ok)
            )
        report.round_trip_us = 1e6 * sorted(trips)[len(trips) // 2]

    sensors = tx_codec["PlantSensors"]
    checker = rx_codec["PlantSensors"].checker(timeout_ticks=3)
    sensors.pack_raw((1, 90000, 10000))
    checker.check(sensors.data)
    corrupted = bytearray(sensors.data)
    corrupted[4] ^= 0x10
    report.e2e_cases["corrupted"] = checker.check(corrupted).name
    report.e2e_cases["repeated"] = checker.check(sensors.data).name
    sensors.pack_raw((2, 90000, 10000))  # this frame is lost
    sensors.pack_raw((3, 90000, 10000))
    report.e2e_cases["skipped"] = checker.check(sensors.data).name
    status = E2EStatus.OK
    for _ in range(4):
        status = checker.tick()
    report.e2e_cases["silence"] = status.name
    return report
