"""An ECU, its service port on loop:// and a client, all in this process.

The client's ``idle`` runs one ECU tick (the port's poll, then the firmware), so requests and
responses go through pyserial's loop:// handler in a fixed order and every test repeats exactly.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ecu.firmware import E2E_NONEWDATA, E2E_OK, Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.service.port import ServicePort, boot
from ecu.service.transport import open_transport
from sil.console.client import ServiceClient


class LoopRig:
    def __init__(self, params: EcuParams, flash: Path | None = None) -> None:
        self.boot = boot(params, flash)
        self.ecu = Ecu(self.boot.table.firmware)
        self.transport = open_transport("loop://")
        self.port = ServicePort(self.transport, self.ecu, self.boot, seed=7)
        self.client = ServiceClient(
            self.transport, timeout_s=5.0, retries=0, idle=self.tick, first_seq=0
        )
        self.i = EcuInputs()
        self.i.sensor_status = self.i.analog_status = self.i.demand_status = E2E_NONEWDATA

    def tick(self) -> None:
        self.ecu.tick(self.port.poll(self.i))

    def ticks(self, n: int) -> None:
        for _ in range(n):
            self.tick()

    def engine_running(self) -> None:
        """Inputs of a running engine with a fresh demand and arm: the ECU warm-starts to RUN."""
        i = self.i
        i.sensor_status = i.analog_status = i.demand_status = E2E_OK
        i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = 100_890, 10_480, 22_200, 1_500
        i.demand_cpct, i.arm, i.stop = 8_968, 1, 0


def start_ecu(flash: Path, tag: str, mode: str = "realtime") -> tuple[subprocess.Popen, str]:
    """`sil ecu --serial pty --flash FLASH` (in real time by default) on a virtual bus of its
    own; returns the process and the pty path it printed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sil.cli", "ecu", "--bus", f"virtual:svc-{os.getpid()}-{tag}"]
        + ["--mode", mode, "--serial", "pty", "--flash", str(flash), "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stderr], [], [], 1.0)
        if ready:
            line = proc.stderr.readline()
            assert line, f"sil ecu exited with {proc.poll()} before serving the port"
            if line.startswith("service port: "):
                return proc, line.split(": ", 1)[1].strip()
    proc.kill()
    raise AssertionError("sil ecu did not print its service port")


@pytest.fixture
def rig() -> LoopRig:
    return LoopRig(EcuParams())


@pytest.fixture
def rig_factory():
    return LoopRig
