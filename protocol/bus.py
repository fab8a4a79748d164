"""Bus selection: one spec string names a python-can bus.

Specs:
    socketcan:vcan0            Linux SocketCAN (virtual vcan0 or a real can0)
    udp                        loopback multicast with a group and port of this run's own
    udp:239.x.y.z[@PORT]       loopback multicast on a named group (default port 43113)
    virtual:NAME               python-can's in-process virtual bus
    slcan-device:PATH          be a USB-CAN adapter: a pseudo-terminal speaking slcan, linked
                               at PATH for the host (slcan:PATH; protocol.slcan_device)
    INTERFACE:CHANNEL          any other python-can interface (pcan:PCAN_USBBUS1, kvaser:0,
                               slcan:/dev/ttyACM0, ...) for hardware in the loop

Without a spec, :func:`default_spec` picks ``socketcan:vcan0`` when that interface exists and is
up, else a loopback multicast bus of this run's own, and says which it chose. Simulated traffic
never leaves the machine (see :mod:`protocol.udp_loopback`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import random
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can

UDP_DEFAULT_PORT = 43113


class BusSpecError(ValueError):
    """A bus spec that cannot be parsed or opened; the message is one line for the user."""


class BusDriverError(BusSpecError):
    """A python-can interface whose driver (its library, Python module or platform) is not
    available on this machine."""


# what python-can raises when an interface's driver is missing: its own error, a failed import,
# or (kvaser) a call to a function of the library that never loaded
_MISSING_DRIVER = (can.CanInterfaceNotImplementedError, ImportError, NameError, AttributeError)
_DRIVER_WORDS = ("library", "driver", "dll", "not installed", "only supported on", "install ")


@dataclass(frozen=True)
class BusSpec:
    interface: str  # python-can interface name, or "udp" for the loopback multicast bus
    channel: str
    port: int | None = None

    def __str__(self) -> str:
        if self.interface == "udp":
            return f"udp:{self.channel}@{self.port}"
        return f"{self.interface}:{self.channel}"


def _known_interfaces() -> frozenset[str]:
    return frozenset(can.interfaces.VALID_INTERFACES)


def unique_udp_spec(rng: random.Random | None = None) -> BusSpec:
    """A loopback multicast group and port of this run's own, so parallel runs never meet."""
    rng = rng or random.Random(int.from_bytes(os.urandom(8), "little"))
    group = f"239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}"
    return BusSpec("udp", group, rng.randrange(20000, 60000))


def parse_spec(spec: str) -> BusSpec:
    """Parse a bus spec string (see the module docstring) without opening anything."""
    text = spec.strip()
    if not text:
        raise BusSpecError("empty bus spec")
    if text == "udp":
        return unique_udp_spec()
    interface, sep, channel = text.partition(":")
    if not sep or not channel:
        raise BusSpecError(
            f"bus spec '{spec}' needs INTERFACE:CHANNEL "
            "(socketcan:vcan0, udp:239.255.1.2@43113, virtual:NAME, pcan:PCAN_USBBUS1)"
        )
    if interface == "udp":
        group, at, port_text = channel.partition("@")
        port = UDP_DEFAULT_PORT
        if at:
            if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
                raise BusSpecError(f"bus spec '{spec}': port '{port_text}' is not 1..65535")
            port = int(port_text)
        return BusSpec("udp", group, port)
    if interface == "udp_multicast":
        raise BusSpecError(
            f"bus spec '{spec}': use udp:GROUP[@PORT] (kept on this host) for udp_multicast"
        )
    if interface == "slcan-device":
        return BusSpec(interface, channel)
    if interface not in _known_interfaces():
        known = ", ".join(sorted((_known_interfaces() - {"udp_multicast"}) | {"udp"}))
        raise BusSpecError(f"bus spec '{spec}': unknown interface '{interface}' (known: {known})")
    return BusSpec(interface, channel)


def socketcan_is_up(channel: str = "vcan0") -> bool:
    """True when the network interface exists and is administratively up."""
    flags = Path("/sys/class/net") / channel / "flags"
    try:
        return bool(int(flags.read_text().strip(), 16) & 0x1)  # IFF_UP
    except (OSError, ValueError):
        return False


def default_spec() -> tuple[BusSpec, str]:
    """The bus to use when none is named, and one line saying why."""
    if socketcan_is_up("vcan0"):
        return BusSpec("socketcan", "vcan0"), "bus: socketcan:vcan0 (vcan0 is up)"
    spec = unique_udp_spec()
    return spec, f"bus: {spec} (no vcan0 here; loopback multicast of this run's own)"


def open_bus(spec: str | BusSpec, **kwargs) -> can.BusABC:
    """Open the python-can bus a spec names; failures become one :class:`BusSpecError` line
    (:class:`BusDriverError` when the interface's driver is missing)."""
    parsed = parse_spec(spec) if isinstance(spec, str) else spec
    try:
        if parsed.interface == "udp":
            from protocol.udp_loopback import LoopbackUdpMulticastBus

            return LoopbackUdpMulticastBus(
                parsed.channel, parsed.port or UDP_DEFAULT_PORT, **kwargs
            )
        if parsed.interface == "slcan-device":
            from protocol.slcan_device import SlcanDeviceBus

            return SlcanDeviceBus(parsed.channel, **kwargs)
        if parsed.interface == "socketcan" and not socketcan_is_up(parsed.channel):
            raise BusSpecError(
                f"bus {parsed}: network interface '{parsed.channel}' does not exist or is down "
                f"(create it with: ip link add dev {parsed.channel} type vcan && "
                f"ip link set up {parsed.channel})"
            )
    except BusSpecError:
        raise
    except (can.CanError, OSError, ImportError, ValueError) as exc:
        raise BusSpecError(f"bus {parsed}: {_one_line(str(exc))}") from exc
    return _open_python_can(parsed, **kwargs)


def _open_python_can(parsed: BusSpec, **kwargs) -> can.BusABC:
    """A python-can interface's bus. Its driver is third-party code that may fail in any way
    (or log warnings on import): every failure becomes one line, with what it logged."""
    with _driver_notes() as notes:
        try:
            return can.Bus(interface=parsed.interface, channel=parsed.channel, **kwargs)
        except Exception as exc:  # a driver's failure, whatever its type
            error = _driver_error(parsed, exc, notes)
        # the half-built bus (freed with the exception) may log on its way out: still captured
    raise error


def _driver_error(parsed: BusSpec, exc: Exception, notes: list[str]) -> BusSpecError:
    """The one-line error for a python-can interface that failed to open."""
    text = _one_line(str(exc))
    if isinstance(exc, (NameError, AttributeError)) or not text:
        text = _one_line("; ".join(notes)) or "python-can could not load its library"
    if isinstance(exc, _MISSING_DRIVER) or any(word in text.lower() for word in _DRIVER_WORDS):
        return BusDriverError(
            f"bus {parsed}: the {parsed.interface} driver is not installed or cannot load on "
            f"this machine: {text}"
        )
    return BusSpecError(f"bus {parsed}: cannot open it: {text}")


@contextlib.contextmanager
def _driver_notes() -> Iterator[list[str]]:
    """Collect what is logged (python-can's drivers warn on import when their library is
    missing) instead of letting it reach stderr; yields the messages."""
    notes: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            notes.append(record.getMessage())

    handler, root = _Collect(logging.WARNING), logging.getLogger()
    root.addHandler(handler)
    try:
        yield notes
    finally:
        root.removeHandler(handler)


def _one_line(text: str) -> str:
    return " ".join(text.split())
