"""python-can's ``udp_multicast`` bus, kept on this machine.

python-can binds its socket to every address of the host, joins its group on the interface of
the default route and sends with a hop limit of 1, which puts simulated traffic (and the IGMP
membership reports of the join) on the local network. This backend keeps the same wire format
but:

- joins the group on the loopback interface only (``lo``, by its index) and sends through it
  (IP_MULTICAST_IF 127.0.0.1), so no membership report goes out on a network interface; a plain
  ``udp_multicast`` peer, which joins and sends on the default route's interface, is therefore not
  on the same bus;
- sends with multicast TTL 0: a datagram never leaves the host;
- loops multicast back to local sockets (IP_MULTICAST_LOOP = 1);
- binds the socket to the multicast group address, not to the wildcard address, so nothing
  listens on any unicast address of the machine; it sends from a second socket, connected to
  the group (its route is looked up once, not per datagram), which joins no group and, being
  connected, accepts datagrams only from the group address, which sends none;
- does not hear its own frames (multicast loopback delivers them to the sender too): each bus
  marks what it sends with a channel token of its own and drops frames that carry it (a frame
  received has the bus's channel, the group, as python-can's buses give theirs);
- hears, once told who they are (:meth:`~LoopbackUdpMulticastBus.admit`), only the senders of a
  run: each datagram names its sender by that token, so a frame of any other sender (a second
  ECU, a replay of a log) is handed to a hook, which keeps it (an XCP master's) or counts it
  and drops it, whatever it carries; until it is told, it can hold what comes
  (:meth:`~LoopbackUdpMulticastBus.hold`: a node waiting to start, whose queue would overflow
  with other runs' traffic), and hears it later by the same rules;
- filters by frame ID in the kernel: :meth:`~can.BusABC.set_filters` attaches a socket filter
  (classic BPF, :func:`kernel_filter`) that drops datagrams whose ID matches no filter before
  they are queued, so a node is not woken for frames it does not want (python-can's software
  filter still checks every frame that passes);
- has a frame path for the node drivers (:meth:`~LoopbackUdpMulticastBus.send_frame`,
  :meth:`~LoopbackUdpMulticastBus.recv_frame`, :meth:`~LoopbackUdpMulticastBus.recv_frames`):
  the same datagrams without python-can message objects or msgpack, waiting in the kernel.

Only IPv4 administratively scoped groups (239.0.0.0/8) are accepted.
"""

from __future__ import annotations

import ctypes
import errno
import ipaddress
import math
import os
import select
import socket
import struct
import time
from collections import deque
from collections.abc import Callable, Collection, Sequence

import can
import msgpack
from can.interfaces.udp_multicast.bus import SO_TIMESTAMPNS
from can.interfaces.udp_multicast.utils import is_msgpack_installed
from can.typechecking import CanFilter, CanFilters

ADMIN_SCOPE = ipaddress.ip_network("239.0.0.0/8")
MAX_DATAGRAM = 4096
SO_ATTACH_FILTER, SO_DETACH_FILTER = 26, 27  # <asm-generic/socket.h>
_TIMESPEC = struct.Struct("@ll")
_TIMEVAL = struct.Struct("@ll")  # SO_RCVTIMEO: seconds, microseconds
_ANCILLARY_SIZE = socket.CMSG_SPACE(_TIMESPEC.size)
LOOPBACK_INTERFACE, LOOPBACK_ADDRESS = "lo", "127.0.0.1"

# Where python-can's packing puts the frame ID: a msgpack map of 11 entries whose first keys are
# "timestamp" (a float64) and "arbitration_id"; the filter's offsets count from the UDP header.
_UDP_HEADER = 8
_PREFIX_CHECKS = (  # (offset in the datagram, bytes there)
    (0, b"\x8b\xa9ti"),  # fixmap(11), fixstr(9) "ti(mestamp)"
    (11, b"\xcb"),  # float64
    (20, b"\xaearb"),  # fixstr(14) "arb(itration_id)"
    (31, b"n_id"),
)
_ID_TYPE = 35  # the ID's msgpack type byte, its value after it
_MIN_DATAGRAM = _ID_TYPE + 3
_UINT8, _UINT16 = 0xCC, 0xCD  # msgpack types; below 0x80 the type byte is the value itself
# a classical data frame's datagram: _STAMP, the timestamp's 8 bytes, the middle (ID, flags,
# channel, DLC, data header), the data and _TAIL (is_fd, bitrate_switch, error_state_indicator)
_STAMP = b"\x8b\xa9timestamp\xcb"
_TAIL = b"\xa5is_fd\xc2\xaebitrate_switch\xc2\xb5error_state_indicator\xc2"
_STAMP_END = len(_STAMP) + 8
_TAIL_START, _DATA_8 = -len(_TAIL), -len(_TAIL) - 8  # where the tail and 8 bytes of data start
_KNOWN_MAX = 1024  # datagram middles cached per bus (senders times frame IDs)
HELD_MAX = 200_000  # datagrams held at most (hold): about 30 MB; past that they wait in the kernel
PRECISE_WAIT_S = 0.02  # shorter receive timeouts wait in epoll, not in SO_RCVTIMEO

# classic BPF opcodes (<linux/filter.h>)
_LD_W, _LD_H, _LD_B, _LD_LEN = 0x20, 0x28, 0x30, 0x80
_JA, _JEQ, _JGE, _AND, _TAX, _TXA, _RET = 0x05, 0x15, 0x35, 0x54, 0x07, 0x87, 0x06
_ACCEPT, _DROP = "accept", "drop"
Frame = tuple[int, bytes] | can.Message | None


class _LoopbackSocket:
    """The group's UDP sockets, configured as the module docstring says."""

    @staticmethod
    def open(group: str, port: int) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            sock.bind((group, port))
        except OSError as error:
            sock.close()
            raise can.CanInitializationError(
                f"could not open loopback multicast {group}:{port}: {error}"
            ) from error
        try:
            _keep_on_loopback(sock)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, _loopback_request(group))
        except OSError as error:
            sock.close()
            raise can.CanInitializationError(
                f"could not join multicast group {group} on the loopback interface "
                f"{LOOPBACK_INTERFACE} ({error.strerror or error}); the udp bus needs "
                f"{LOOPBACK_INTERFACE} up with {LOOPBACK_ADDRESS} (ip link set lo up)"
            ) from error
        return sock

    @staticmethod
    def open_sender(group: str, port: int) -> socket.socket:
        """The socket the bus sends from, connected to the group (see the module docstring)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            _keep_on_loopback(sock)
            sock.connect((group, port))
            return sock
        except OSError as error:
            sock.close()
            raise can.CanInitializationError(
                f"could not send to loopback multicast {group}:{port} through "
                f"{LOOPBACK_INTERFACE} ({error.strerror or error}); the udp bus needs "
                f"{LOOPBACK_INTERFACE} up with {LOOPBACK_ADDRESS} (ip link set lo up)"
            ) from error


def _keep_on_loopback(sock: socket.socket) -> None:
    """Multicast from ``sock`` goes out through the loopback interface with TTL 0, and is looped
    back to the host's sockets."""
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(LOOPBACK_ADDRESS))


def _loopback_request(group: str) -> bytes:
    """``struct ip_mreqn`` joining ``group`` on the loopback interface, named by its index (the
    kernel then joins there whatever the routes say)."""
    index = socket.if_nametoindex(LOOPBACK_INTERFACE)
    return socket.inet_aton(group) + socket.inet_aton(LOOPBACK_ADDRESS) + struct.pack("@i", index)


def kernel_filter(filters: Sequence[CanFilter]) -> bytes | None:
    """A classic BPF socket filter passing the datagrams whose frame ID matches a filter's
    ``can_id`` under its ``can_mask``, as packed by python-can; datagrams laid out otherwise
    pass too (python-can's software filter decides). None when no program can express it."""
    program: list[tuple] = [(_LD_LEN, 0, 0, 0)]
    program.append((_JGE, 0, _ACCEPT, _UDP_HEADER + _MIN_DATAGRAM))
    for offset, expected in _PREFIX_CHECKS:
        load = {4: _LD_W, 1: _LD_B}[len(expected)]
        program.append((load, 0, 0, _UDP_HEADER + offset))
        program.append((_JEQ, 0, _ACCEPT, int.from_bytes(expected, "big")))
    program += [
        (_LD_B, 0, 0, _UDP_HEADER + _ID_TYPE),
        (_JGE, 0, "id", 0x80),  # positive fixint: the type byte is the ID
        (_JEQ, "uint8", 0, _UINT8),
        (_JEQ, "uint16", _ACCEPT, _UINT16),  # wider IDs: left to the software filter
        ("uint8", _LD_B, 0, 0, _UDP_HEADER + _ID_TYPE + 1),
        (_JA, 0, 0, "id"),
        ("uint16", _LD_H, 0, 0, _UDP_HEADER + _ID_TYPE + 1),
        ("id", _TAX, 0, 0, 0),
    ]
    for f in filters:
        mask = f["can_mask"]
        program += [(_TXA, 0, 0, 0), (_AND, 0, 0, mask), (_JEQ, _ACCEPT, 0, f["can_id"] & mask)]
    program += [(_DROP, _RET, 0, 0, 0), (_ACCEPT, _RET, 0, 0, 0xFFFFFFFF)]
    return _assemble(program)


def _assemble(program: list[tuple]) -> bytes | None:
    """Instructions ``([label,] code, jt, jf, k)`` to ``struct sock_filter`` bytes; jump targets
    are 0 (the next instruction) or a label; None when a jump is too long for the format."""
    labels = {ins[0]: i for i, ins in enumerate(program) if isinstance(ins[0], str)}
    out = []
    for i, ins in enumerate(program):
        code, jt, jf, k = ins[1:] if isinstance(ins[0], str) else ins
        jt, jf = (labels[j] - i - 1 if isinstance(j, str) else j for j in (jt, jf))
        if code == _JA:
            k, jt = labels[k] - i - 1, 0
        if not (0 <= jt <= 255 and 0 <= jf <= 255):
            return None
        out.append(struct.pack("HBBI", code, jt, jf, k))
    return b"".join(out)


class LoopbackUdpMulticastBus(can.BusABC):
    """A ``udp_multicast`` bus whose traffic stays on the local host (see module docstring)."""

    def __init__(self, channel: str, port: int | str = 43113, **kwargs) -> None:
        """``channel``: the group (239.x.y.z); ``port``: its UDP port (python-can's config and
        command-line tools may give it as text). Registered with python-can as the interface
        ``turbojet_udp``."""
        is_msgpack_installed()
        try:
            port = int(port)
        except ValueError:
            raise can.CanInitializationError(f"port {port!r} is not a number") from None
        try:
            address = ipaddress.ip_address(channel)
        except ValueError:
            raise can.CanInitializationError(f"'{channel}' is not an IP address") from None
        if address not in ADMIN_SCOPE:
            raise can.CanInitializationError(
                f"group {channel} is not an administratively scoped IPv4 group (239.x.y.z)"
            )
        self._socket = _LoopbackSocket.open(channel, port)
        try:
            self._sender = _LoopbackSocket.open_sender(channel, port)
        except can.CanInitializationError:
            self._socket.close()
            raise
        self._poll = select.epoll()
        self._poll.register(self._socket, select.EPOLLIN)
        self._send_timeout: float | None = None
        self._recv_timeout: float | None = None  # the socket's SO_RCVTIMEO (None: for ever)
        self._accepted: dict[int, bool] = {}  # standard frame ID -> passes the filters
        self._known: dict[bytes, int] = {}  # datagram middle -> frame ID, or -1: skipped
        self._heads: dict[tuple[int, int], bytes] = {}  # (frame ID, length) -> datagram head
        self._token = f"udp-{os.urandom(6).hex()}"
        self._admitted: frozenset[str] | None = None  # the senders heard (None: every one)
        self._on_other: Callable[[str, tuple[int, bytes] | can.Message], bool] | None = None
        self._held: deque[bytes] = deque()  # datagrams read by hold(), heard first
        self._can_protocol = can.CanProtocol.CAN_20
        self.channel = channel  # (every frame received is on it)
        self.channel_info = f"udp loopback multicast {channel}:{port}"
        super().__init__(channel, **kwargs)

    @property
    def token(self) -> str:
        """This bus's sender token: every datagram it sends names it."""
        return self._token

    def admit(
        self,
        senders: Collection[str],
        on_other: Callable[[str, tuple[int, bytes] | can.Message], bool] | None = None,
    ) -> None:
        """From now on hear only the frames of ``senders`` (tokens of other buses): any other
        sender's frame that passes the filters is given with its sender's token to
        ``on_other``, and heard only if that returns True (without it: dropped)."""
        self._admitted = frozenset(senders)
        self._on_other = on_other
        self._known = {}  # (verdicts learned before: of any sender)

    def hold(self, timeout: float) -> None:
        """Read the datagrams that come within ``timeout`` seconds without hearing them yet: the
        receives hear them first, in order, by the rules then in force (:meth:`admit`)."""
        deadline = time.monotonic() + timeout
        while len(self._held) < HELD_MAX and self._wait(max(0.0, deadline - time.monotonic())):
            self._held.append(self._read(MAX_DATAGRAM)[0])
            if time.monotonic() >= deadline:
                return

    # -- sending --------------------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd:
            raise can.CanOperationError("cannot send FD message over bus with CAN FD disabled")
        fields = {  # python-can's layout (pack_message), with this bus's token as the channel
            "timestamp": msg.timestamp,
            "arbitration_id": msg.arbitration_id,
            "is_extended_id": msg.is_extended_id,
            "is_remote_frame": msg.is_remote_frame,
            "is_error_frame": msg.is_error_frame,
            "channel": self._token,
            "dlc": msg.dlc,
            "data": msg.data,
            "is_fd": msg.is_fd,
            "bitrate_switch": msg.bitrate_switch,
            "error_state_indicator": msg.error_state_indicator,
        }
        self._send(msgpack.packb(fields, use_bin_type=True), timeout)

    def send_frame(self, frame_id: int, data: bytes | bytearray | memoryview) -> None:
        """Send a classical data frame with a standard ID: the datagram :meth:`send` sends for
        ``can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)``, made
        without the message object from a head kept per ID and length (the node drivers'
        path, :mod:`protocol.node`)."""
        head = self._heads.get((frame_id, len(data)))
        if head is None:
            head = self._heads[frame_id, len(data)] = frame_head(self._token, frame_id, len(data))
        self._send(head + data + _TAIL, None)

    def _send(self, datagram: bytes, timeout: float | None) -> None:
        if timeout != self._send_timeout:
            self._send_timeout = timeout
            self._sender.settimeout(timeout)
        try:
            if self._sender.send(datagram) < len(datagram):
                raise TimeoutError
        except TimeoutError:
            raise can.CanTimeoutError from None
        except OSError as error:
            raise can.CanOperationError("failed to send via socket") from error

    # -- receiving ------------------------------------------------------------------------------
    def recv_frame(self, timeout: float | None) -> tuple[int, bytes] | can.Message | None:
        """The next frame heard that passes the filters, or None after ``timeout`` seconds (None:
        wait for ever): a classical data frame with a standard ID as ``(frame_id, data)``, any
        other as the ``can.Message`` :meth:`recv` gives. Lighter than :meth:`recv` (no message
        object, no kernel timestamp): the node drivers' path, :mod:`protocol.node`."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while (datagram := self._receive(timeout)) is not None:
            frame = self._frame(datagram)
            if frame is not None:
                return frame
            if deadline is not None:
                timeout = max(0.0, deadline - time.monotonic())
        return None

    def _receive(self, timeout: float | None) -> bytes | None:
        """The next datagram, or None after ``timeout`` seconds (None: wait for ever). A long
        wait is the kernel's (SO_RCVTIMEO): one system call per datagram. SO_RCVTIMEO counts in
        scheduler ticks (it ends up to 4-10 ms late), so a wait shorter than ``PRECISE_WAIT_S``
        (a real-time node waiting for its next period) is an epoll wait, to the millisecond."""
        if self._held:
            return self._held.popleft()
        flags = 0
        if timeout is not None and timeout < PRECISE_WAIT_S:
            if timeout > 0.0 and not self._wait(timeout):
                return None
            flags = socket.MSG_DONTWAIT
        elif timeout != self._recv_timeout:
            micro = 0 if timeout is None else max(1, math.ceil(timeout * 1e6))  # 0: for ever
            timeval = _TIMEVAL.pack(micro // 1_000_000, micro % 1_000_000)
            self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, timeval)
            self._recv_timeout = timeout
        try:
            return self._socket.recv(MAX_DATAGRAM, flags)
        except BlockingIOError:  # the timeout passed
            return None
        except OSError as error:
            raise can.CanOperationError(f"failed to receive from the socket: {error}") from error

    def recv_frames(self, timeout: float | None) -> list[tuple[int, bytes] | can.Message]:
        """Every frame queued that passes the filters, as :meth:`recv_frame` gives them, after
        waiting up to ``timeout`` seconds for the first datagram (none came, or none passed:
        an empty list). The recorder's path: one wake-up for all the frames queued."""
        frames = [f for datagram in self._held if (f := self._frame(datagram)) is not None]
        self._held.clear()
        timeout = 0.0 if frames else timeout
        poll, recv = self._poll.poll, self._socket.recv
        try:
            while poll(timeout):
                frame = self._frame(recv(MAX_DATAGRAM))
                if frame is not None:
                    frames.append(frame)
                timeout = 0.0
        except OSError as error:
            raise can.CanOperationError(f"failed to receive from the socket: {error}") from error
        return frames

    def _frame(self, datagram: bytes) -> tuple[int, bytes] | can.Message | None:
        """What :meth:`recv_frame` gives for a datagram, None for those it skips (our own, CAN
        FD, filtered out). An 8-byte frame laid out as :func:`frame_head` lays it out is known
        by its middle (all but the timestamp and the data), cached with the verdict, and taken
        apart without msgpack."""
        verdict = self._known.get(datagram[_STAMP_END:_DATA_8])
        if verdict is None or not datagram.startswith(_STAMP) or not datagram.endswith(_TAIL):
            return self._decode(datagram)
        return (verdict, datagram[_DATA_8:_TAIL_START]) if verdict >= 0 else None

    def _decode(self, datagram: bytes) -> tuple[int, bytes] | can.Message | None:
        fields = self._fields(datagram)
        if fields is None:
            return None
        frame = _classical_standard(fields)
        if frame is None:
            msg = self._message(fields, time.time())
            return self._admitted_only(fields, msg) if self._matches_filters(msg) else None
        accepted = self._accepts(frame[0])
        if accepted and self._admitted_only(fields, frame) is None:
            return None
        self._learn(datagram, fields.get("channel"), frame, accepted)
        return frame if accepted else None

    def _admitted_only(self, fields: dict, frame: tuple[int, bytes] | can.Message) -> Frame:
        """``frame`` if its sender is heard (:meth:`admit`) or the hook keeps it, else None."""
        sender = fields.get("channel")
        if self._admitted is None or sender in self._admitted:
            return frame
        keep = self._on_other is not None and self._on_other(str(sender), frame)
        return frame if keep else None

    def _learn(
        self, datagram: bytes, channel: object, frame: tuple[int, bytes], accepted: bool
    ) -> None:
        """Cache the verdict on an 8-byte frame whose datagram has :func:`frame_head`'s layout."""
        frame_id, data = frame
        if len(data) != 8 or type(channel) is not str or len(self._known) >= _KNOWN_MAX:
            return
        middle = frame_head(channel, frame_id, 8)[_STAMP_END:]
        if datagram[_STAMP_END:] == middle + data + _TAIL:
            self._known[middle] = frame_id if accepted else -1

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._held:
            datagram, ancillary = self._held.popleft(), []
        elif not self._wait(timeout):
            return None, False
        else:
            datagram, ancillary = self._read(MAX_DATAGRAM, _ANCILLARY_SIZE)
        fields = self._fields(datagram)
        if fields is None:
            return None, False
        msg = self._message(fields, _timestamp(ancillary))
        if self._matches_filters(msg) and self._admitted_only(fields, msg) is None:
            return None, False
        return msg, False

    def _wait(self, timeout: float | None) -> bool:
        """Wait until a datagram can be read (False: ``timeout`` seconds passed first)."""
        try:
            return bool(self._poll.poll(timeout))
        except OSError as error:
            raise can.CanOperationError(f"failed to wait for the socket: {error}") from error

    def _read(self, size: int, ancillary_size: int = 0) -> tuple[bytes, list]:
        try:
            datagram, ancillary, _, _ = self._socket.recvmsg(size, ancillary_size)
        except OSError as error:
            raise can.CanOperationError(f"failed to receive from the socket: {error}") from error
        return datagram, ancillary

    def _fields(self, datagram: bytes) -> dict | None:
        """A datagram's message fields; None for our own frames (looped back by the kernel)
        and CAN FD frames (this bus is CAN 2.0)."""
        try:
            fields = msgpack.unpackb(datagram, raw=False)
            if fields.get("channel") == self._token or fields.get("is_fd"):
                return None
            return fields
        except Exception as exception:
            raise can.CanOperationError("could not unpack received message") from exception

    def _message(self, fields: dict, timestamp: float) -> can.Message:
        """The datagram's frame as python-can's message on this bus: its channel is the bus's
        (the group), as on any python-can bus, not the sender's token the datagram carries."""
        try:
            return can.Message(check=True, **{**fields, "timestamp": timestamp,
                                              "channel": self.channel})  # fmt: skip
        except Exception as exception:
            raise can.CanOperationError("could not unpack received message") from exception

    def _accepts(self, frame_id: int) -> bool:
        """A classical data frame with this standard ID passes the filters (cached per ID)."""
        accepted = self._accepted.get(frame_id)
        if accepted is None:
            probe = can.Message(arbitration_id=frame_id, is_extended_id=False)
            accepted = self._accepted[frame_id] = self._matches_filters(probe)
        return accepted

    def _apply_filters(self, filters: CanFilters | None) -> None:
        self._accepted = {}
        self._known = {}
        program = kernel_filter(filters) if filters else None
        if program is None:
            try:
                self._socket.setsockopt(socket.SOL_SOCKET, SO_DETACH_FILTER, 0)
            except OSError as error:
                if error.errno != errno.ENOENT:  # ENOENT: no filter was attached
                    raise
            return
        code = ctypes.create_string_buffer(program)  # the kernel copies it while attaching
        fprog = struct.pack("@HP", len(program) // 8, ctypes.addressof(code))
        self._socket.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)

    def fileno(self) -> int:
        return self._socket.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._poll.close()
        self._socket.close()
        self._sender.close()

    @property
    def socket(self) -> socket.socket:
        return self._socket

    @property
    def sender(self) -> socket.socket:
        """The socket it sends from (connected to the group)."""
        return self._sender


def frame_head(channel: str, frame_id: int, length: int) -> bytes:
    """The datagram of a classical data frame with a standard ID up to its data, as python-can
    lays it out (``pack_message``) with a zero timestamp: the datagram is head + data + tail."""
    fields = {
        "timestamp": 0.0,
        "arbitration_id": frame_id,
        "is_extended_id": False,
        "is_remote_frame": False,
        "is_error_frame": False,
        "channel": channel,
        "dlc": length,
        "data": bytes(length),
        "is_fd": False,
        "bitrate_switch": False,
        "error_state_indicator": False,
    }
    packed = msgpack.packb(fields, use_bin_type=True)
    return packed[: len(packed) - length - len(_TAIL)]


def _classical_standard(fields: dict) -> tuple[int, bytes] | None:
    """``(frame_id, data)`` of a valid classical data frame with a standard ID, else None."""
    frame_id, data = fields.get("arbitration_id"), fields.get("data")
    if (
        fields.get("is_extended_id")
        or fields.get("is_remote_frame")
        or fields.get("is_error_frame")
        or type(frame_id) is not int
        or not 0 <= frame_id <= 0x7FF
        or type(data) is not bytes
        or len(data) > 8
        or fields.get("dlc", len(data)) != len(data)
    ):
        return None
    return frame_id, data


def _timestamp(ancillary: list[tuple[int, int, bytes]]) -> float:
    """Receive time: the kernel's SO_TIMESTAMPNS stamp when present, else now."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            seconds, nanoseconds = _TIMESPEC.unpack(data)
            return seconds + nanoseconds * 1e-9
    return time.time()
