"""python-can's ``udp_multicast`` bus, kept on this machine.

python-can binds its socket to every address of the host and sends with a hop limit of 1, which
puts simulated traffic on the local network. This backend keeps the same wire format (so it
interoperates with plain ``udp_multicast`` peers on the same group and port) but:

- sends with multicast TTL 0: a datagram never leaves the host;
- loops multicast back to local sockets (IP_MULTICAST_LOOP = 1);
- binds the socket to the multicast group address, not to the wildcard address, so nothing
  listens on any unicast address of the machine;
- does not hear its own frames (multicast loopback delivers them to the sender too): each bus
  marks what it sends with a channel token of its own and drops frames that carry it.

Only IPv4 administratively scoped groups (239.0.0.0/8) are accepted.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import struct

import can
from can.interfaces.udp_multicast.bus import (
    SO_TIMESTAMPNS,
    GeneralPurposeUdpMulticastBus,
    UdpMulticastBus,
)
from can.interfaces.udp_multicast.utils import is_msgpack_installed

ADMIN_SCOPE = ipaddress.ip_network("239.0.0.0/8")


class _LoopbackMulticastSocket(GeneralPurposeUdpMulticastBus):
    def _create_socket(self, address_family: socket.AddressFamily) -> socket.socket:
        if address_family != socket.AF_INET:
            raise OSError("only IPv4 groups are used for loopback multicast")
        sock = socket.socket(address_family, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            try:
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self.timestamp_nanosecond = True
            except OSError:
                self.timestamp_nanosecond = False
            sock.bind((self.group, self.port))
            request = socket.inet_aton(self.group) + struct.pack("@I", socket.INADDR_ANY)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, request)
            return sock
        except OSError as error:
            sock.close()
            raise can.CanInitializationError(
                f"could not open loopback multicast {self.group}:{self.port}: {error}"
            ) from error


class LoopbackUdpMulticastBus(UdpMulticastBus):
    """A ``udp_multicast`` bus whose traffic stays on the local host (see module docstring)."""

    def __init__(self, channel: str, port: int, **kwargs) -> None:
        is_msgpack_installed()
        try:
            address = ipaddress.ip_address(channel)
        except ValueError:
            raise can.CanInitializationError(f"'{channel}' is not an IP address") from None
        if address not in ADMIN_SCOPE:
            raise can.CanInitializationError(
                f"group {channel} is not an administratively scoped IPv4 group (239.x.y.z)"
            )
        can.BusABC.__init__(self, channel, **kwargs)
        self._multicast = _LoopbackMulticastSocket(channel, port, 0)
        self._can_protocol = can.CanProtocol.CAN_20
        self.channel_info = f"udp loopback multicast {channel}:{port}"
        self._token = f"udp-{os.urandom(6).hex()}"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        msg.channel = self._token
        super().send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg, filtered = super()._recv_internal(timeout)
        if msg is not None and msg.channel == self._token:
            return None, False  # our own frame, looped back by the kernel
        return msg, filtered

    @property
    def socket(self) -> socket.socket:
        return self._multicast._socket
