"""pyXCP against `sil ecu --flash FILE` (Python and C) with a real-time plant at rest: a glow-plug
test asked for through the bench words runs and times out; an arm and a stop in the spin-up
count a start and a STOPPED abort in the logbook, read by SHORT_UPLOAD at the A2L's addresses;
the ECU saves it at rest, and after a restart on the same flash image reads the same counts."""

from __future__ import annotations

import os
import select
import struct
import subprocess
import time
from pathlib import Path

import pytest

from ecu import actuator_tests as T
from ecu import modes as M
from tests.xcp.conftest import read_a2l

pytestmark = pytest.mark.slow


def _wait_for_line(proc: subprocess.Popen, prefix: bytes, timeout: float = 90) -> None:
    pending = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stderr.fileno()], [], [], 1.0)
        if not ready:
            continue
        chunk = os.read(proc.stderr.fileno(), 65536)
        assert chunk, f"the process exited with {proc.poll()}: {pending!r}"
        pending += chunk
        if any(line.startswith(prefix) for line in pending.split(b"\n")):
            return
    raise AssertionError(f"no {prefix!r} line: {pending!r}")


class Ecu:
    """`sil ecu --impl IMPL --flash FLASH` in real time beside a plant at rest."""

    def __init__(self, impl: str, flash: Path, udp_group: tuple[str, int], sil_process) -> None:  # noqa: ANN001
        bus = f"udp:{udp_group[0]}@{udp_group[1]}"
        quiet = {"stdout": subprocess.DEVNULL}
        self.plant = sil_process("plant", "--bus", bus, "--realtime", "--standstill", **quiet)
        self.ecu = sil_process("ecu", "--bus", bus, "--impl", impl, "--mode", "realtime",
                               "--flash", str(flash), **quiet)  # fmt: skip
        _wait_for_line(self.ecu, b"xcp: ")

    def close(self) -> None:
        for proc in (self.ecu, self.plant):
            proc.terminate()
        for proc in (self.ecu, self.plant):
            proc.communicate(timeout=20)


def _read(x, m: dict) -> int:  # noqa: ANN001 (a pyXCP Master; an A2L measurement)
    code = {"UBYTE": "B", "UWORD": "H", "SWORD": "h", "SLONG": "i"}[m["type"]]
    size = struct.calcsize(code)
    return struct.unpack("<" + code, x.shortUpload(size, m["address"]))[0]


def _write(x, c: dict, value: int) -> None:  # noqa: ANN001 (a pyXCP Master; a CHARACTERISTIC)
    x.setMta(c["address"])
    x.download(struct.pack("<i", value))


def _until(x, m: dict, wanted: int, timeout: float = 20) -> None:  # noqa: ANN001
    deadline = time.monotonic() + timeout
    while _read(x, m) != wanted:
        assert time.monotonic() < deadline, (m["name"], _read(x, m), wanted)
        time.sleep(0.02)


@pytest.mark.parametrize("impl", ["python", "c"])
def test_pyxcp_runs_a_test_and_reads_the_logbook_over_a_restart(
    impl, tmp_path, udp_group, sil, sil_process, xcp_tools
):
    a2l_path = tmp_path / "ecu.a2l"
    done = sil("a2l", "--impl", impl, "--out", str(a2l_path))
    assert done.returncode == 0, done.stderr
    a2l = read_a2l(a2l_path)
    meas = {m["name"]: m for m in a2l["measurements"]}
    bench = {c["name"]: c for c in a2l["characteristics"] if c["name"].startswith("bench_")}
    flash = tmp_path / "flash.bin"
    ecu = Ecu(impl, flash, udp_group, sil_process)
    try:
        with xcp_tools.master("turbojet_udp", udp_group[0], port=udp_group[1]) as x:
            x.connect()
            x.cond_unlock()
            _until(x, meas["inputs_valid"], 1)
            assert _read(x, meas["log_starts"]) == 0
            # the glow plug for 0.5 s: running, then over by itself
            _write(x, bench["bench_test_ms"], 500)
            _write(x, bench["bench_test"], T.GLOW)
            _until(x, meas["test_active"], T.GLOW, timeout=2)
            assert _read(x, meas["igniter"]) == 1
            _until(x, meas["test_active"], T.NONE, timeout=3)
            assert _read(x, meas["igniter"]) == 0
            # an arm, stopped in the spin-up: a start, a STOPPED abort, saved at rest
            _write(x, bench["bench_arm"], 1)
            _until(x, meas["mode"], M.ARMED)
            _write(x, bench["bench_stop"], 1)
            _until(x, meas["mode"], M.OFF)
            assert _read(x, meas["log_starts"]) == 1
            assert _read(x, meas["log_aborts_stopped"]) == 1
            assert _read(x, meas["log_last_shutdown"]) == 1  # OPERATOR_STOP
            time.sleep(1.0)  # the save at rest, one flash operation a tick
            x.disconnect()
    finally:
        ecu.close()
    ecu = Ecu(impl, flash, udp_group, sil_process)  # power-up on the same flash image
    try:
        with xcp_tools.master("turbojet_udp", udp_group[0], port=udp_group[1]) as x:
            x.connect()
            assert _read(x, meas["log_starts"]) == 1
            assert _read(x, meas["log_aborts_stopped"]) == 1
            assert _read(x, meas["log_runs"]) == 0
            x.disconnect()
    finally:
        ecu.close()
