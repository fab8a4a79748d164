"""An ECU with its XCP slave, all in this process: frames go in, ticks run, frames come out."""

from __future__ import annotations

import functools
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from ecu.firmware import E2E_NONEWDATA, E2E_OK, Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.service.port import boot
from ecu.xcp import codes as C
from ecu.xcp.seed_key import key_for
from ecu.xcp.slave import XcpSlave


class SlaveRig:
    """``request(*bytes)`` serves one command at a tick boundary and returns what the slave
    sent; ``tick()`` runs the firmware (and the DAQ sampling after it)."""

    def __init__(self, params: EcuParams | None = None, flash: Path | None = None) -> None:
        self.boot = boot(params or EcuParams(), flash)
        self.ecu = Ecu(self.boot.table.firmware)
        self.slave = XcpSlave(self.ecu, self.boot, seed=3)
        self.sent: list[bytes] = []
        self.i = EcuInputs()
        self.i.sensor_status = self.i.analog_status = self.i.demand_status = E2E_NONEWDATA

    def send(self, data: bytes) -> None:
        self.sent.append(bytes(data))

    def serve(self) -> list[bytes]:
        self.sent = []
        self.slave.serve(self.send)
        return self.sent

    def request(self, *frame: int | bytes) -> bytes:
        """One command; its single answer (or b'' when none came)."""
        data = b"".join(bytes((x,)) if isinstance(x, int) else x for x in frame)
        self.slave.receive(data)
        out = self.serve()
        assert len(out) <= 1, out
        return out[0] if out else b""

    def tick(self, n: int = 1) -> list[bytes]:
        dtos: list[bytes] = []
        for _ in range(n):
            self.sent = []
            self.slave.serve(self.send)
            self.ecu.tick(self.slave.inputs(self.i))
            self.slave.sample(self.send)
            dtos += self.sent
        return dtos

    def connect(self) -> bytes:
        return self.request(C.Cmd.CONNECT, 0)

    def unlock(self, resource: int) -> bytes:
        seed = self.request(C.Cmd.GET_SEED, 0, resource)
        assert seed[0] == C.PID_RES and seed[1] == 4
        key = key_for(seed[2:6])
        return self.request(C.Cmd.UNLOCK, len(key), key)

    def short_upload(self, address: int, size: int) -> bytes:
        return self.request(C.Cmd.SHORT_UPLOAD, size, 0, 0, struct.pack("<I", address))

    def set_mta(self, address: int) -> bytes:
        return self.request(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", address))

    def download(self, address: int, data: bytes) -> bytes:
        assert self.set_mta(address) == b"\xff"
        return self.request(C.Cmd.DOWNLOAD, len(data), data)

    def engine_running(self) -> None:
        """Inputs of a running engine with a fresh demand and arm: the ECU warm-starts to RUN."""
        i = self.i
        i.sensor_status = i.analog_status = i.demand_status = E2E_OK
        i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = 100_890, 10_480, 22_200, 1_500
        i.demand_cpct, i.arm, i.stop = 8_968, 1, 0

    def at_rest(self) -> None:
        """Sensor and analog frames of a still, cold engine; no Demand frames."""
        i = self.i
        i.sensor_status = i.analog_status = E2E_OK
        i.demand_status = E2E_NONEWDATA
        i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = 0, 2_900, 22_200, 0


@pytest.fixture
def rig() -> SlaveRig:
    return SlaveRig()


@pytest.fixture
def rig_factory():
    return SlaveRig


@pytest.fixture(scope="session")
def sil(sil):
    """tests/conftest.py's ``sil``, 120 s for a command unless a test gives its own timeout."""
    return functools.partial(sil, timeout=120)


def pyxcp_master(
    interface: str, channel: str, *, policy=None, bus=None, handle_errors=False, **params
):
    """pyXCP's master as it is, configured in code (no pyxcp_conf.py): XCP on CAN over the
    python-can ``interface`` (``turbojet_udp``, ``slcan``, ...) on ``channel``, the DBC's IDs,
    the seed and key of ecu.xcp.seed_key; ``params``: the interface's further arguments (for
    the loopback bus, ``port``); ``bus``: a python-can bus to use instead of opening one;
    ``handle_errors``: pyXCP's own error handling (off: refusals raise XcpResponseError)."""
    import logging

    from pyxcp.config import PyXCP
    from pyxcp.master import Master
    from traitlets.config import Config

    from protocol.dbc import xcp_frame_ids

    cmd, res = xcp_frame_ids()
    c = Config()
    c.Transport.layer = "CAN"
    c.Transport.Can.interface = interface
    c.Transport.Can.channel = channel
    c.Transport.Can.can_id_master = cmd
    c.Transport.Can.can_id_slave = res
    c.Transport.Can.bitrate = 500_000
    if interface == "slcan":
        c.SlCan.sleep_after_open = 0.0
    else:
        c.CanCustom.extra_params = params
    c.General.seed_n_key_function = lambda resource, seed: key_for(bytes(seed))
    # pyXCP's error handler ends the process (SystemExit) on an error it cannot recover from;
    # without it a refusal is an XcpResponseError carrying the slave's error code
    c.General.disable_error_handling = not handle_errors
    app = PyXCP(config=c)
    app.log_level = logging.WARNING
    app._setup_logger()
    from pyxcp.config import General, Transport

    app.general = General(config=app.config, parent=app)
    app.transport = Transport(parent=app)
    return Master("CAN", config=app, policy=policy, transport_layer_interface=bus)


PYXCP_TYPES = {"UBYTE": "U8", "SBYTE": "I8", "UWORD": "U16", "SWORD": "I16", "SLONG": "I32"}


def daq_collector(measurements: list[tuple[str, int, str]], event: int = 0):
    """A pyXCP DAQ policy that keeps every sample of one DAQ list on ``event`` in memory:
    ``measurements`` (name, address, A2L type); ``.names`` and ``.rows`` (receive time, the
    slave's timestamp, the values in ``.names`` order)."""
    import logging

    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy

    daq_list = DaqList(
        name="measurements",
        event_num=event,
        stim=False,
        enable_timestamps=True,
        measurements=[(n, a, 0, PYXCP_TYPES[t]) for n, a, t in measurements],
        priority=0,
        prescaler=1,
    )

    class Collector(DaqOnlinePolicy):
        def __init__(self) -> None:
            super().__init__([daq_list], logger=logging.getLogger("pyxcp.daq"))
            self.pid_off = False  # (pyXCP 0.29 sets it only when it reads its own config)
            self.rows: list[tuple[int, int, list]] = []

        @property
        def names(self) -> list[str]:
            return [h[0] for h in daq_list.headers]

        def initialize(self) -> None:
            pass

        def finalize(self) -> None:
            pass

        def on_daq_list(self, daq: int, ts0: int, ts1: int, payload: list) -> None:
            self.rows.append((ts0, ts1, list(payload)))

    return Collector()


class SlcanHub:
    """The ECU behind its pseudo-terminal (``slcan-device:ECU_TTY``) joined to the loopback bus
    (where the plant is) and to a second pseudo-terminal (``MASTER_TTY``) that the master opens
    with python-can's slcan: one bus (tests/xcp/slcan_hub.py, in a process of its own)."""

    def __init__(self, ecu_tty: Path, master_tty: Path, group: str, port: int) -> None:
        script = Path(__file__).with_name("slcan_hub.py")
        self.proc = subprocess.Popen(
            [sys.executable, str(script), str(ecu_tty), str(master_tty), group, str(port)],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout.readline().startswith("hub: ready"), self.proc.poll()

    def close(self) -> None:
        self.proc.terminate()
        self.proc.communicate(timeout=10)


READER = Path(__file__).with_name("read_a2l.py")


def read_a2l(path: Path) -> dict:
    """What pya2ldb reads in ``path`` (tests/xcp/read_a2l.py, in a process of its own); the
    parser's own complaints fail the test."""
    import json

    done = subprocess.run(
        [sys.executable, str(READER), str(path)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    output = done.stdout + done.stderr
    complaints = [line for line in output.splitlines() if "[error]" in line or "[warn" in line]
    assert not complaints, complaints
    line = next(line for line in done.stdout.splitlines() if line.startswith("JSON "))
    return json.loads(line[5:])


@pytest.fixture(scope="module")
def a2l(tmp_path_factory, sil) -> dict:
    """The A2L `sil a2l` writes, as pya2ldb reads it."""
    path = tmp_path_factory.mktemp("a2l") / "turbojet_ecu.a2l"
    done = sil("a2l", "--out", str(path))
    assert done.returncode == 0, done.stderr
    return read_a2l(path)


@pytest.fixture(scope="session")
def xcp_tools():
    """The helpers of the tests that run pyXCP against `sil` processes."""

    class Tools:
        master = staticmethod(pyxcp_master)
        daq = staticmethod(daq_collector)
        hub = SlcanHub

    return Tools
