"""Bus specs, clear errors, and simulated traffic kept on this machine."""

import logging
import random
import socket
import struct
from pathlib import Path

import can
import pytest

from protocol.bus import BusSpec, BusSpecError, default_spec, open_bus, parse_spec, unique_udp_spec


def test_specs_parse():
    assert parse_spec("socketcan:vcan0") == BusSpec("socketcan", "vcan0")
    assert parse_spec("virtual:bench") == BusSpec("virtual", "bench")
    assert parse_spec("udp:239.255.1.2@47000") == BusSpec("udp", "239.255.1.2", 47000)
    assert parse_spec("udp:239.255.1.2").port == 43113
    assert parse_spec("pcan:PCAN_USBBUS1") == BusSpec("pcan", "PCAN_USBBUS1")
    assert parse_spec("udp").interface == "udp"


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ("", "empty"),
        ("vcan0", "INTERFACE:CHANNEL"),
        ("canbus:0", "unknown interface 'canbus'"),
        ("udp:239.1.1.1@0", "port '0'"),
        ("udp_multicast:ff15::1", "kept on this host"),
    ],
)
def test_bad_specs_name_what_is_wrong(spec, words):
    with pytest.raises(BusSpecError, match=words):
        parse_spec(spec)


def test_missing_interface_and_non_local_group_are_clear_errors():
    with pytest.raises(BusSpecError, match="'vcan9' does not exist or is down"):
        open_bus("socketcan:vcan9")
    with pytest.raises(BusSpecError, match="not an administratively scoped"):
        open_bus("udp:224.0.0.1@47000")


def test_default_is_vcan0_when_up_else_own_udp(monkeypatch):
    monkeypatch.setattr("protocol.bus.socketcan_is_up", lambda channel="vcan0": True)
    assert default_spec()[0] == BusSpec("socketcan", "vcan0")
    monkeypatch.setattr("protocol.bus.socketcan_is_up", lambda channel="vcan0": False)
    spec, why = default_spec()
    assert spec.interface == "udp" and "udp:239.255." in why


def test_each_run_gets_its_own_group_and_port():
    specs = {str(unique_udp_spec()) for _ in range(50)}
    assert len(specs) == 50


def test_udp_socket_never_leaves_the_host():
    spec = unique_udp_spec(random.Random(7))
    with open_bus(spec) as bus:
        sock = bus.socket
        assert sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL) == 0
        assert sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP) == 1
        # bound to the group, not to a unicast or wildcard address: nothing listens on the LAN
        assert sock.getsockname() == (spec.channel, spec.port)
        # it sends from a socket connected to the group, which joins nothing and hears nothing
        sender = bus.sender
        assert sender.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL) == 0
        assert sender.getpeername() == (spec.channel, spec.port)
        for each in (sock, sender):  # both send through the loopback interface
            interface = each.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)
            assert socket.inet_ntoa(interface) == "127.0.0.1"


def _igmp_memberships() -> dict[str, set[str]]:
    """The kernel's IPv4 multicast memberships: group address -> the interfaces joined."""
    members: dict[str, set[str]] = {}
    device = ""
    for line in Path("/proc/net/igmp").read_text().splitlines()[1:]:
        fields = line.split()
        if not line[0].isspace():  # "Idx Device : Count Querier", one per interface
            device = fields[1]
        elif fields:  # "Group Users Timer Reporter", the group as the kernel's 32-bit word
            group = socket.inet_ntoa(struct.pack("=I", int(fields[0], 16)))
            members.setdefault(group, set()).add(device)
    return members


def test_udp_bus_joins_its_group_on_loopback_only():
    spec = unique_udp_spec(random.Random(19))
    assert spec.channel not in _igmp_memberships()
    with open_bus(spec) as a, open_bus(spec) as b:
        a.send(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
        assert b.recv(1.0).arbitration_id == 0x100
        assert _igmp_memberships()[spec.channel] == {"lo"}
    assert spec.channel not in _igmp_memberships()


def test_udp_round_trip_between_two_endpoints_and_isolation():
    rng = random.Random(11)
    mine, other = unique_udp_spec(rng), unique_udp_spec(rng)
    with open_bus(mine) as a, open_bus(mine) as b, open_bus(other) as c:
        a.send(can.Message(arbitration_id=0x100, data=bytes(range(8)), is_extended_id=False))
        got = b.recv(2.0)
        assert (
            got is not None and got.arbitration_id == 0x100 and bytes(got.data) == bytes(range(8))
        )
        # the frame's channel is the bus's (python-can's convention), not the sender's token
        assert got.channel == b.channel == mine.channel != a.token
        assert c.recv(0.2) is None  # another run's bus hears nothing


def test_unicast_to_the_port_is_not_received():
    spec = unique_udp_spec(random.Random(3))
    with open_bus(spec) as bus, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(b"\x00" * 16, ("127.0.0.1", spec.port))
        assert bus.recv(0.2) is None


def test_virtual_bus():
    with open_bus("virtual:test_bus_py") as a, open_bus("virtual:test_bus_py") as b:
        a.send(can.Message(arbitration_id=0x80, data=b"\x01" * 8, is_extended_id=False))
        assert b.recv(1.0).arbitration_id == 0x80


def test_udp_bus_does_not_hear_itself():
    spec = unique_udp_spec(random.Random(5))
    with open_bus(spec) as a, open_bus(spec) as b:
        a.send(can.Message(arbitration_id=0x80, data=bytes(8), is_extended_id=False))
        assert b.recv(1.0).arbitration_id == 0x80
        assert a.recv(0.2) is None


def _queued(sock: socket.socket) -> list[bytes]:
    """Datagrams waiting in a socket's receive queue (read without blocking)."""
    out = []
    while True:
        try:
            out.append(sock.recv(4096, socket.MSG_DONTWAIT))
        except BlockingIOError:
            return out


def test_udp_filters_drop_other_ids_in_the_kernel():
    spec = unique_udp_spec(random.Random(9))
    ids = (0x7, 0x90, 0x110, 0x100, 0x1FFFFFFF, 0x110)  # 1-, 2- and 3-byte msgpack IDs, extended
    with open_bus(spec) as a, open_bus(spec) as b, open_bus(spec) as c:
        b.set_filters([{"can_id": i, "can_mask": 0x1FFFFFFF} for i in (0x7, 0x90, 0x110)])
        for frame_id in ids:
            a.send(
                can.Message(arbitration_id=frame_id, data=bytes(8), is_extended_id=frame_id > 0x7FF)
            )
        heard = [c.recv(1.0).arbitration_id for _ in ids]
        assert heard == list(ids)  # a bus without filters hears everything
        queued = _queued(b.socket)  # the kernel kept only the filter's IDs; the wider 32-bit
        assert len(queued) == 5  # msgpack ID is left to the software filter, which drops it
        b.set_filters(
            [{"can_id": 0x7, "can_mask": 0x1FFFFFFF}, {"can_id": 0x110, "can_mask": 0x7FF}]
        )
        for frame_id in ids:
            a.send(
                can.Message(arbitration_id=frame_id, data=bytes(8), is_extended_id=frame_id > 0x7FF)
            )
        got = []
        while (msg := b.recv(0.2)) is not None:
            got.append(msg.arbitration_id)
        assert got == [0x7, 0x110, 0x110]
        b.set_filters(None)  # detached: everything again
        a.send(can.Message(arbitration_id=0x300, data=bytes(8), is_extended_id=False))
        assert b.recv(1.0).arbitration_id == 0x300


def test_udp_kernel_filter_too_long_falls_back_to_software():
    from protocol.udp_loopback import kernel_filter

    assert kernel_filter([{"can_id": i, "can_mask": 0x7FF} for i in range(3)]) is not None
    assert kernel_filter([{"can_id": i, "can_mask": 0x7FF} for i in range(200)]) is None
    spec = unique_udp_spec(random.Random(13))
    with open_bus(spec) as a, open_bus(spec) as b:
        b.set_filters([{"can_id": i, "can_mask": 0x7FF} for i in range(1, 200)])
        a.send(can.Message(arbitration_id=0x0, data=bytes(8), is_extended_id=False))
        a.send(can.Message(arbitration_id=0x50, data=bytes(8), is_extended_id=False))
        assert b.recv(1.0).arbitration_id == 0x50


def test_udp_frame_path_sends_the_message_datagram_and_reads_frames():
    spec = unique_udp_spec(random.Random(17))
    with open_bus(spec) as a, open_bus(spec) as b:
        payload = bytearray(range(8))
        a.send(can.Message(arbitration_id=0x110, data=payload, is_extended_id=False))
        a.send_frame(0x110, memoryview(payload))
        first, second = _queued(b.socket)
        assert first == second  # the same datagram as python-can's layout, with the token
        a.send_frame(0x80, payload[:3])
        a.send(can.Message(arbitration_id=0x1FFFFFFF, data=bytes(8), is_extended_id=True))
        a.send(can.Message(arbitration_id=0x7, data=bytes(8), is_extended_id=False, dlc=8))
        assert b.recv_frame(1.0) == (0x80, bytes(range(3)))
        extended = b.recv_frame(1.0)  # any other frame comes as python-can's message
        assert isinstance(extended, can.Message) and extended.arbitration_id == 0x1FFFFFFF
        b.set_filters([{"can_id": 0x7, "can_mask": 0x7FF}])
        a.send_frame(0x110, payload)
        assert b.recv_frame(1.0) == (0x7, bytes(8))
        assert b.recv_frame(0.1) is None and a.recv_frame(0.1) is None  # filtered; own frames


def test_a_driver_that_fails_in_any_way_is_one_bus_spec_error(monkeypatch, capsys):
    from protocol.bus import BusDriverError

    def kvaser_without_its_library(**kwargs):
        logging.getLogger("can.kvaser").warning("Kvaser canlib is unavailable.")
        raise NameError("name 'canGetNumberOfChannels' is not defined")

    monkeypatch.setattr(can, "Bus", kvaser_without_its_library)
    with pytest.raises(BusDriverError, match="kvaser driver is not installed.*canlib"):
        open_bus("kvaser:0")
    monkeypatch.setattr(can, "Bus", lambda **kwargs: [][1])  # a driver's own bug
    with pytest.raises(BusSpecError, match=r"^bus pcan:X: cannot open it: list index"):
        open_bus("pcan:X")
    assert capsys.readouterr().err == ""  # what the driver logged is in the error, not on stderr
