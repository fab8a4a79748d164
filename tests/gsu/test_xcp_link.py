"""The page's XCP link in this process, beside an ECU's XCP slave served every 10 ms on a
virtual bus: beside another master (raw command frames on the request identifier, whose
answers nobody reads), it gives a value only from its own answer, else says another master is
on the bus; an ECU that pauses is refused at once while silent, a request it left unanswered
is not taken for a later one, and the link reads again by itself once the ECU runs."""

from __future__ import annotations

import math
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from ecu.firmware import Ecu
from ecu.params import EcuParams
from ecu.service.param_table import TABLE
from ecu.service.port import boot
from ecu.xcp.codes import Cmd
from ecu.xcp.slave import XcpSlave
from sil.console.gsu.xcp_link import SETTLE_S, Unavailable, XcpLink
from sil.record.a2l import A2l, read_a2l

IDS = (0x700, 0x701)
SILENT_S = 0.5


class SlaveOnBus:
    """An ECU's XCP slave on a bus, served every 10 ms unless paused; ``running_for`` as the
    page's live values tell it (how long the ECU has been heard without a silence)."""

    def __init__(self, channel: str) -> None:
        b = boot(EcuParams(), None)
        self.slave = XcpSlave(Ecu(b.table.firmware), b, seed=3)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.paused = threading.Event()
        self.heard_s = time.monotonic()
        self.since_s = self.heard_s - 10.0  # (running for a while)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.01):
            if self.paused.is_set():
                continue
            now = time.monotonic()
            if now - self.heard_s > SILENT_S:
                self.since_s = now
            self.heard_s = now
            while (msg := self.bus.recv(0)) is not None:
                if msg.arbitration_id == IDS[0]:
                    self.slave.receive(bytes(msg.data))
            self.slave.serve(self._send)

    def _send(self, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=IDS[1], data=data, is_extended_id=False))

    def running_for(self) -> float:
        now = time.monotonic()
        return 0.0 if now - self.heard_s > SILENT_S else now - self.since_s

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.bus.shutdown()


@pytest.fixture(scope="module")
def a2l(tmp_path_factory) -> A2l:  # noqa: ANN001
    from sil.commands import a2l as a2l_command

    path = Path(tmp_path_factory.mktemp("a2l")) / "ecu.a2l"
    path.write_text(a2l_command.text_for("python", None, None), "latin-1")
    return read_a2l(path)


@pytest.fixture
def ecu(request: pytest.FixtureRequest) -> Iterator[SlaveOnBus]:
    slave = SlaveOnBus(f"gsu-link-{request.node.name}")
    yield slave
    slave.close()


@pytest.fixture
def link(ecu: SlaveOnBus, a2l: A2l) -> Iterator[XcpLink]:
    bus = can.Bus(interface="virtual", channel=ecu.bus.channel_info.split()[-1])
    link = XcpLink(bus, a2l, IDS, ecu.running_for)
    yield link
    link.close()
    bus.shutdown()


def _default(name: str) -> float:
    spec = next(s for s in TABLE if s.name == name)
    return spec.to_value(spec.to_raw(getattr(EcuParams(), spec.field)))


def test_beside_another_master_a_value_read_is_the_ecus_answer_to_it(
    ecu: SlaveOnBus, link: XcpLink, a2l: A2l
) -> None:
    c = a2l.characteristics
    upload = struct.pack("<BBBBI", Cmd.SHORT_UPLOAD, 4, 0, 0, c["start_egt_limit_k"].address)
    every_s = [0.2]
    stop = threading.Event()

    def another_master() -> None:  # reads of another parameter, every_s apart, 3 at a time
        bus = can.Bus(interface="virtual", channel=ecu.bus.channel_info.split()[-1])
        while not stop.wait(every_s[0]):
            for _ in range(3):
                bus.send(can.Message(arbitration_id=IDS[0], data=upload, is_extended_id=False))
        bus.shutdown()

    assert link.read_characteristic(c["egt_limit_k"]) == _default("egt_limit_k")
    thread = threading.Thread(target=another_master, daemon=True)
    thread.start()
    try:
        read, deadline = [], time.monotonic() + 1.5
        while time.monotonic() < deadline:
            read.append(link.read_characteristic(c["egt_limit_k"]))
        assert set(read) == {_default("egt_limit_k")} and link.watch.foreign >= 9
        assert link.status()["another_master"]
        every_s[0] = 0.02  # the bus never quiet for the link
        time.sleep(0.3)
        with pytest.raises(Unavailable, match="read egt_limit_k: another XCP master is on the bus"):
            link.read_characteristic(c["egt_limit_k"])
    finally:
        stop.set()
        thread.join(2)


def test_a_paused_ecu_is_refused_at_once_and_read_again_once_it_runs(
    ecu: SlaveOnBus, link: XcpLink, a2l: A2l
) -> None:
    c = a2l.characteristics
    assert link.read_characteristic(c["egt_limit_k"]) == _default("egt_limit_k")
    ecu.paused.set()  # not yet known as silent: this request waits at the ECU
    with pytest.raises(Unavailable, match="did not answer within 1 s") as lost:
        link.read_characteristic(c["start_egt_limit_k"])
    assert lost.value.timed_out
    started = time.monotonic()
    with pytest.raises(Unavailable, match="the ECU is silent"):
        link.read_characteristic(c["egt_limit_k"])
    assert time.monotonic() - started < 0.1
    ecu.paused.clear()  # it answers the request that waited
    time.sleep(0.05)
    with pytest.raises(Unavailable, match="only just back"):
        link.read_characteristic(c["egt_limit_k"])
    time.sleep(SETTLE_S)
    assert link.read_characteristic(c["egt_limit_k"]) == _default("egt_limit_k")
    assert math.isclose(
        link.read_characteristic(c["start_egt_limit_k"]), _default("start_egt_limit_k")
    )
