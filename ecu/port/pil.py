"""Processor in the loop: the firmware image (ecu_main.c on board_mps2.c) on QEMU's emulated
Cortex-M4, its CAN link on the loopback interface and its console read here.

The image's CAN link (build.PIL_LINKS) is its Ethernet controller (``eth``: one CAN frame per
Ethernet frame, each a UDP datagram of QEMU's socket network backend; ecu/port/eth_can.py) or its
UART0 speaking slcan (``slcan``: on a loopback TCP port that python-can's ``slcan`` interface
opens as ``socket://127.0.0.1:PORT``, as it would a USB-CAN adapter). The serial link costs QEMU
a round of its event loop per byte, some 22 bytes a frame; the Ethernet link one per frame.

:func:`calibration_block` writes the block the image reads from its flash sector (layout in
ecu_main.h: the parameter words, the XCP slave's identifiers and run record); :class:`PilImage`
starts QEMU with the image and the block, opens the link as a python-can bus and reads the
console: the SysTick calibration, the per-tick profile lines and any refusal or watchdog
reset.

In lockstep QEMU runs with ``-icount shift=0``: its virtual clock advances one nanosecond per
instruction while the CPU runs (and with the wall clock while it sleeps), so SysTick counts around
a tick, scaled by the start-up calibration loop, are the tick's instructions. In real time the
image's SysTick must follow the wall clock, which it does only without instruction counting (with
it, the emulated time fell behind by half here): QEMU runs without it and no profile is taken.
CPU load is reported for a 168 MHz Cortex-M4 at one instruction per cycle (an assumption: flash
wait states and multi-cycle instructions make real cycles somewhat more).
"""

from __future__ import annotations

import shutil
import socket
import struct
import subprocess
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import can

from ecu.firmware_params import FirmwareParams
from ecu.port import build, qemu
from ecu.port.core import param_words
from ecu.port.eth_can import EthCanBus
from ecu.port.qemu import QEMU, QEMU_NOT_FOUND
from ecu.port.xcp_run import RUN_WORDS

MAGIC = b"ECUC"
VERSION = 2
LOCKSTEP, PROFILE, XCP = 1, 2, 4
CALIB_ADDRESS = 0x000F0000  # mps2_an386_pil.ld: the calibration sector
CORE_HZ = 168e6  # the Cortex-M4 the load is reported for (STM32F4 class)
START_TIMEOUT_S = 30.0  # QEMU up, image ready


class PilError(RuntimeError):
    """The image could not be started, or refused its calibration block."""


def calibration_block(
    params: FirmwareParams,
    *,
    lockstep: bool,
    guard_s: float = 1.0,
    watchdog_ms: int = 250,
    profile: bool = True,
    xcp: XcpBlock | None = None,
) -> bytes:
    """The calibration block (ecu_main.h) for ``params``, with its CRC-32; ``xcp``: the XCP
    slave's identifiers, seed and run record (None: no slave)."""
    words = param_words(params)
    flags = (LOCKSTEP if lockstep else 0) | (PROFILE if profile else 0) | (XCP if xcp else 0)
    guard_ms = max(1, round(guard_s * 1e3))
    body = MAGIC + struct.pack(
        f"<5I{len(words)}i", VERSION, flags, guard_ms, watchdog_ms, len(words), *words
    )
    x = xcp or XcpBlock((0, 0), 1, [0] * RUN_WORDS)
    if len(x.run) != RUN_WORDS:
        raise PilError(f"XCP run record of {len(x.run)} words: {RUN_WORDS} expected")
    body += struct.pack(f"<3I{RUN_WORDS}i", *x.ids, x.seed or 1, *x.run)
    return body + struct.pack("<I", zlib.crc32(body))


@dataclass(frozen=True)
class XcpBlock:
    """The XCP slave's part of the calibration block: its CAN IDs (master to ECU, ECU to
    master), the seeds' generator start, the run record (ecu.port.xcp_run.run_record)."""

    ids: tuple[int, int]
    seed: int
    run: list[int]


@dataclass
class Profile:
    """What the console's per-tick lines say: SysTick counts of the node call that ran each
    tick and of its ecu_tick, turned into instructions by the calibration."""

    cal_counts: int = 0
    cal_instructions: int = 0
    ticks: int = 0
    node_sum: int = 0
    node_max: int = 0
    core_sum: int = 0
    core_max: int = 0
    resets: int = 0
    refused: str | None = None
    ready: bool = False
    lines: list[str] = field(default_factory=list)  # anything else the console said

    def instructions(self, counts: float) -> float:
        if not self.cal_counts:
            return float("nan")
        return counts * self.cal_instructions / self.cal_counts

    def summary(self) -> dict:
        """Instructions per tick (mean, max) of the core and of the whole node call, and the CPU
        load they make at 100 Hz and 1 kHz on a 168 MHz Cortex-M4 at one instruction per cycle;
        without a profile (real time) only the resets."""
        out: dict = {"watchdog_resets": self.resets}
        if self.lines:
            out["console"] = self.lines[-10:]
        if not self.ticks:
            return out
        n = self.ticks
        node_mean = self.instructions(self.node_sum / n)
        return {
            "ticks_profiled": self.ticks,
            "instructions_per_tick": {
                "core_mean": round(self.instructions(self.core_sum / n), 1),
                "core_max": round(self.instructions(self.core_max)),
                "node_mean": round(node_mean, 1),
                "node_max": round(self.instructions(self.node_max)),
            },
            "cpu_load_pct": {
                "100_Hz": round(100.0 * node_mean * 100 / CORE_HZ, 3),
                "1_kHz": round(100.0 * node_mean * 1000 / CORE_HZ, 3),
                "assumes": "168 MHz Cortex-M4, one instruction per cycle",
            },
            **out,
        }

    def take(self, line: str) -> None:
        word, _, rest = line.partition(" ")
        if word == "K":
            node, _, core = rest.partition(" ")
            try:
                counts = int(node), int(core)
            except ValueError:  # a line cut short (QEMU stopped while it was written)
                self.lines.append(line)
                return
            self.ticks += 1
            self.node_sum += counts[0]
            self.core_sum += counts[1]
            self.node_max = max(self.node_max, counts[0])
            self.core_max = max(self.core_max, counts[1])
        elif word == "CAL" and all(part.isdigit() for part in rest.split(" ", 1)):
            counts, _, instructions = rest.partition(" ")
            self.cal_counts, self.cal_instructions = int(counts), int(instructions)
        elif word == "READY":
            self.ready = True
        elif word == "CONFIG":
            self.refused = rest.removeprefix("BAD ").strip()
        elif line == "RESET watchdog":
            self.resets += 1
            self.ready = False  # until it says READY again
        elif line:
            self.lines.append(line)


def _free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def image_sizes(elf: Path) -> dict[str, int]:
    """Flash (text + data) and RAM (data + bss, without the calibration sector) in bytes."""
    out = subprocess.run(
        ["arm-none-eabi-size", "-A", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    size = {
        parts[0]: int(parts[1])
        for parts in (line.split() for line in out.splitlines())
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit()
    }
    text = size.get(".text", 0) + size.get(".ARM.exidx", 0)
    ram = size.get(".data", 0) + size.get(".bss", 0) + size.get(".noinit", 0)
    return {"flash_bytes": text + size.get(".data", 0), "ram_bytes": ram}


class PilImage:
    """QEMU running the firmware image with ``block`` in its calibration sector and its CAN on
    ``link`` (build.PIL_LINKS), on the loopback interface only.

    :meth:`open_bus` gives the link as a python-can bus; :attr:`profile` fills from the console
    as the image runs. A context manager: leaving it stops QEMU.
    """

    def __init__(
        self,
        block: bytes,
        *,
        link: str = "eth",
        elf: Path | None = None,
        icount: bool = True,
    ) -> None:
        if link not in build.PIL_LINKS:
            raise PilError(f"unknown CAN link {link!r} (known: {', '.join(build.PIL_LINKS)})")
        if not shutil.which(QEMU):
            raise PilError(QEMU_NOT_FOUND)
        self.link = link
        self.elf = elf or build.arm_pil_image(link)
        self._dir = tempfile.TemporaryDirectory(prefix="ecu-pil-")
        self._cal = Path(self._dir.name) / "calibration.bin"
        self._cal.write_bytes(block)
        self.icount = icount
        self.profile = Profile()
        self.proc: subprocess.Popen | None = None
        self.port = 0  # QEMU's end of the link on 127.0.0.1 (TCP for slcan, UDP for eth)
        self._host: socket.socket | None = None  # eth: our UDP end, bound before QEMU starts
        self._readers: list[threading.Thread] = []  # the console's and QEMU's stderr's

    @property
    def url(self) -> str:
        """Where the image's link is: a pyserial URL (slcan) or its UDP address (eth)."""
        if self.link == "slcan":
            return f"socket://127.0.0.1:{self.port}"
        return f"udp://127.0.0.1:{self.port}"

    def start(self) -> None:
        """Start QEMU. On slcan it waits (halted) until the port is connected; on eth the image
        runs at once (:meth:`wait_ready`)."""
        if self.link == "eth":
            self._host = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._host.bind(("127.0.0.1", 0))
            self.port = _free_port(socket.SOCK_DGRAM)
            self.proc = self._popen()
            self._start_readers()
            return
        for _ in range(5):  # a port taken between choosing it and QEMU's bind: another one
            self.port = _free_port()
            self.proc = self._popen()
            said = self._until_listening()
            if said is None:
                self._start_readers()
                return
            if "Address already in use" not in said:
                raise PilError(f"{QEMU} did not start: {said.strip() or 'no message'}")
        raise PilError(f"{QEMU}: no free loopback port after 5 tries")

    def _popen(self) -> subprocess.Popen:
        return subprocess.Popen(
            self._command(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def _start_readers(self) -> None:
        self._readers = [threading.Thread(target=self._read_console, daemon=True),
                         threading.Thread(target=self._drain_stderr, daemon=True)]  # fmt: skip
        for reader in self._readers:
            reader.start()

    def _read_to_the_end(self) -> None:
        """Wait (2 s at most) for the readers to take what QEMU wrote before it ended."""
        for reader in self._readers:
            reader.join(2.0)

    def _until_listening(self) -> str | None:
        """None once QEMU says it waits for the slcan connection; else what it said before it
        exited."""
        assert self.proc is not None and self.proc.stderr is not None
        said = []
        for line in self.proc.stderr:
            if "waiting for connection" in line:
                return None
            said.append(line)
        self.proc.wait()
        return "".join(said)

    def _drain_stderr(self) -> None:
        assert self.proc is not None and self.proc.stderr is not None
        for line in self.proc.stderr:
            if "terminating on signal" not in line:  # (our own stop)
                self.profile.lines.append(f"qemu: {line.strip()}")

    def _command(self) -> list[str]:
        if self.link == "eth":
            assert self._host is not None
            host_port = self._host.getsockname()[1]
            link = [
                "-serial",
                "null",
                "-nic",
                f"socket,model=lan9118,udp=127.0.0.1:{host_port},localaddr=127.0.0.1:{self.port}",
            ]
        else:
            link = [
                "-serial",
                f"tcp:127.0.0.1:{self.port},server=on,wait=on,nodelay=on",
                "-nic",
                "none",
            ]
        return [
            *qemu.command(icount=self.icount),
            *link,
            "-serial",
            "stdio",
            "-device",
            f"loader,file={self._cal},addr={CALIB_ADDRESS:#x},force-raw=on",
            "-kernel",
            str(self.elf),
        ]

    def _read_console(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            self.profile.take(line.strip())

    def console(self, line: str) -> None:
        """Send a command line to the image's console (ecu_main.h)."""
        assert self.proc is not None and self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def open_bus(self) -> can.BusABC:
        """The image's CAN link as a python-can bus (on slcan this starts the image running)."""
        if self.link == "eth":
            assert self._host is not None
            return EthCanBus(self._host, ("127.0.0.1", self.port))
        bus = can.Bus(interface="slcan", channel=self.url, sleep_after_open=0)
        # each frame is one small write: without TCP_NODELAY the next one waits for an ACK
        # (Nagle's algorithm against delayed ACKs: 40 ms a tick); pyserial does not set it
        sock = getattr(getattr(bus, "serialPortOrig", None), "_socket", None)
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return bus

    def wait_ready(self, timeout: float = START_TIMEOUT_S) -> None:
        """Until the image says READY; PilError when it refused its block or QEMU stopped."""
        deadline = time.monotonic() + timeout
        while not self.profile.ready:
            if self.profile.refused is not None:
                raise PilError(f"the image refused its calibration block: {self.profile.refused}")
            if self.proc is None or self.proc.poll() is not None:
                self._read_to_the_end()  # (its last lines may still be on their way)
                said = " | ".join(self.profile.lines[-4:]) or "no message"
                raise PilError(f"{QEMU} exited before the image was ready: {said}")
            if time.monotonic() > deadline:
                raise PilError(f"the image was not ready within {timeout:g} s")
            time.sleep(0.005)

    def exit_code(self) -> int | None:
        """QEMU's exit code once it has ended (None while it runs, or before it started)."""
        return None if self.proc is None else self.proc.poll()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._read_to_the_end()
        if self._host is not None:
            self._host.close()
        self._dir.cleanup()

    def __enter__(self) -> PilImage:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
