"""pyXCP, as it is, the master of the ECU's XCP slave on a bus: `sil ecu --mode realtime` with a
plant at rest (`sil plant --realtime --standstill`), the Python ECU (``--impl python``), the C
node with the C slave (``--impl c``) and the firmware image in QEMU (``--impl pil``), over (a)
the loopback bus by its python-can interface name ``turbojet_udp`` and (b), for the Python ECU,
slcan: the ECU behind a pseudo-terminal (``slcan-device:``), the master on python-can's
``slcan`` interface.

The master connects, reads the identification and the A2L's name, unlocks with seed and key,
uploads every CHARACTERISTIC of the A2L and finds the Python ECU's values (and, the Python ECU
running with ``--serial pty`` too, its service port's), is refused the writes the parameter
checks refuse (with their XCP errors), lowers a fuel schedule's breakpoint with the engine
stopped and sees it read back and in the start the bench's arm then flies (the pump held under
the lowered acceleration line), and runs a DAQ list of 20 measurements on the control tick with
no sample lost."""

from __future__ import annotations

import json
import os
import select
import struct
import subprocess
import time
from pathlib import Path

import pytest
from pyxcp.types import XcpResponseError

from ecu import start_sequencer as Q
from ecu.params import EcuParams
from ecu.service.param_table import TABLE
from ecu.service.port import boot
from ecu.service.transport import open_transport
from ecu.xcp import memory as MEM
from ecu.xcp.a2l import SCHEDULES, a2l_name
from sil.console.client import ServiceClient

pytestmark = pytest.mark.slow
INDEX = {spec.name: k for k, spec in enumerate(TABLE)}
DAQ_NAMES = (
    "ticks", "mode", "fault_word", "speed_rpm", "speed_ref", "egt", "pump_voltage", "pump_duty",
    "pump_enable", "supply", "pump_current", "pump_health", "owner", "inputs_valid", "ap21",
    "ap22", "lambda", "theta21", "kx1", "kr",
)  # fmt: skip


def _lines_until(proc: subprocess.Popen, *prefixes: str, timeout: float = 90) -> dict[str, str]:
    """The first line of the process's stderr starting with each prefix (what follows it). The
    pipe is read as it comes (os.read): lines that arrive together are all seen."""
    found: dict[str, str] = {}
    deadline = time.monotonic() + timeout
    pending = b""
    fd = proc.stderr.fileno()
    while len(found) < len(prefixes):
        assert time.monotonic() < deadline, f"no {prefixes} line: {found}"
        ready, _, _ = select.select([fd], [], [], 1.0)
        if not ready:
            continue
        chunk = os.read(fd, 65536)
        assert chunk, f"the process exited with {proc.poll()}: {pending.decode()}"
        *lines, pending = (pending + chunk).split(b"\n")
        for line in (raw.decode() for raw in lines):
            for prefix in prefixes:
                if line.startswith(prefix) and prefix not in found:
                    found[prefix] = line[len(prefix) :].strip()
    return found


class Bench:
    """A real-time plant at rest and the ECU of ``impl`` (the Python one with its service port
    on a pty; a flash image but in the loop) on ``link``: 'udp' (both on the loopback bus) or
    'slcan' (the ECU behind a pty, joined to the plant's loopback bus by :class:`SlcanHub`)."""

    def __init__(self, link: str, tmp: Path, udp_group: tuple[str, int], tools,  # noqa: ANN001
                 sil_process, impl: str = "python") -> None:  # fmt: skip
        self.link, self.tmp, self.tools, self.impl = link, tmp, tools, impl
        self.sil_process = sil_process
        self.group, self.port = udp_group
        self.hub = None
        self.stats = tmp / "ecu.json"

    def __enter__(self) -> Bench:
        udp = f"udp:{self.group}@{self.port}"
        ecu_bus = udp if self.link == "udp" else f"slcan-device:{self.tmp / 'ecu.tty'}"
        self.plant = self.sil_process("plant", "--bus", udp, "--realtime", "--standstill")
        extra = {
            "python": ("--serial", "pty", "--flash", str(self.tmp / "flash.bin")),
            "c": ("--flash", str(self.tmp / "flash.bin")),
            "pil": (),
        }[self.impl]
        self.ecu = self.sil_process(
            "ecu", "--bus", ecu_bus, "--impl", self.impl, "--mode", "realtime", *extra,
            "--stats-file", str(self.stats),
        )  # fmt: skip
        port = ("service port: ",) if self.impl == "python" else ()
        lines = _lines_until(self.ecu, *port, "xcp: ")
        self.service_port = lines.get("service port: ")
        if self.link == "slcan":
            self.hub = self.tools.hub(
                self.tmp / "ecu.tty", self.tmp / "master.tty", self.group, self.port
            )
        return self

    def master(self, policy=None):  # noqa: ANN001, ANN201 (a pyXCP policy and Master)
        master = self.tools.master
        if self.link == "udp":
            return master("turbojet_udp", self.group, port=self.port, policy=policy)
        return master("slcan", str(self.tmp / "master.tty"), policy=policy)

    def __exit__(self, *exc: object) -> None:
        for proc in (self.ecu, self.plant):
            proc.terminate()
        for proc in (self.ecu, self.plant):
            proc.communicate(timeout=20)
        if self.hub is not None:
            self.hub.close()

    def summary(self) -> dict:
        return json.loads(self.stats.read_text())


def _i32(*values: int) -> bytes:
    return struct.pack(f"<{len(values)}i", *values)


def _measure(x, name: str) -> int:  # noqa: ANN001 (a pyXCP Master)
    k = MEM.MEAS_INDEX[name]
    m = MEM.MEASUREMENTS[k]
    code = MEM.TYPES[m.datatype][0]
    return struct.unpack("<" + code, x.shortUpload(m.size, MEM.measurement_address(k)))[0]


def _refusal(x, address: int, data: bytes) -> str:  # noqa: ANN001
    x.setMta(address)
    with pytest.raises(XcpResponseError) as refused:
        x.download(data)
    return str(refused.value.get_error_code())


@pytest.mark.parametrize(
    ("impl", "link"), [("python", "udp"), ("python", "slcan"), ("c", "udp"), ("pil", "udp")]
)
def test_pyxcp_calibrates_and_measures_a_realtime_ecu(
    impl, link, tmp_path, udp_group, a2l, xcp_tools, sil_process
):
    params = EcuParams()
    by_name = {m["name"]: m for m in a2l["measurements"]}
    daq = xcp_tools.daq([(n, by_name[n]["address"], by_name[n]["type"]) for n in DAQ_NAMES])
    with Bench(link, tmp_path, udp_group, xcp_tools, sil_process, impl) as bench:
        with bench.master() as x:
            _calibrate(x, bench, a2l, params)
        # a second connection: a DAQ list of 20 measurements on the control tick, their types
        # from the A2L, for 2 s: no sample lost
        with bench.master(policy=daq) as x:
            x.connect()
            x.getCommModeInfo()
            x.cond_unlock("DAQ")
            daq.setup()
            daq.start()
            time.sleep(2.0)
            daq.stop()
            x.disconnect()
    ticks = [row[daq.names.index("ticks")] for _, _, row in daq.rows]
    assert len(ticks) >= 150 and ticks == list(range(ticks[0], ticks[0] + len(ticks)))
    stamps = [ts1 for _, ts1, _ in daq.rows]
    periods = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    assert 9.5e6 < sum(periods) / len(periods) < 10.5e6  # ns: the 100 Hz tick, the ECU's clock
    xcp = bench.summary()["xcp"]
    if impl != "pil":  # (the image's counters stay in the image)
        assert xcp["errors"] == {"OUT_OF_RANGE": 1, "VERIFY": 1, "WRITE_PROTECTED": 1}
        assert xcp["queue_overflow"] == 0 and xcp["ignored_not_connected"] == 0


def _calibrate(x, bench: Bench, a2l: dict, params: EcuParams) -> None:  # noqa: ANN001 (Master)
    """Connect, identify, unlock, upload every CHARACTERISTIC, be refused, lower a breakpoint
    and see it in the start the bench's arm flies."""
    res = x.connect()
    assert (res.maxCto, res.maxDto, res.resource.calpag, res.resource.daq) == (8, 8, 1, 1)
    assert x.getCommModeInfo().commModeOptional.masterBlockMode
    assert x.identifier(0).startswith("turbojet-ecu 0.1 build ")
    assert x.identifier(1) == "turbojet_ecu"
    assert x.getCurrentProtectionStatus() == {
        "dbg": False, "pgm": False, "stim": False, "daq": True, "calpag": True,
    }  # fmt: skip
    x.cond_unlock()
    assert not any(x.getCurrentProtectionStatus().values())

    # every CHARACTERISTIC of the A2L, uploaded, is the Python ECU's value (and the service
    # port's, on the Python ECU)
    python_ecu = dict(zip((s.name for s in TABLE), boot(params, None).table.raws(), strict=True))
    client = None
    if bench.service_port is not None:
        client = ServiceClient(open_transport(bench.service_port), timeout_s=5.0, retries=1)
    uploaded = 0
    for c in a2l["characteristics"]:
        if c["name"].startswith("bench_"):
            continue
        x.setMta(c["address"])
        values = struct.unpack(f"<{c['points']}i", x.fetch(4 * c["points"]))
        if c["name"] in SCHEDULES:
            names = [f"{c['name']}[{k}]" for k in range(c["points"])]
        else:
            names = [next(s.name for s in TABLE if a2l_name(s.name) == c["name"])]
        assert list(values) == [python_ecu[n] for n in names], c["name"]
        if client is not None:
            assert list(values) == [client.get(n)["raw"] for n in names], c["name"]
        uploaded += 1
    assert uploaded == len(a2l["characteristics"]) - len(MEM.BENCH)

    # refused as the parameter checks refuse it, with the XCP error that says why
    egt_limit = MEM.parameter_address(INDEX["egt_limit_k"])
    assert _refusal(x, egt_limit, _i32(1500 << 16)) == "ERR_OUT_OF_RANGE"  # limits 800..1400
    line_1 = MEM.parameter_address(INDEX["accel_line_v[1]"])
    assert _refusal(x, line_1, _i32(1 << 24)) == "ERR_VERIFY"  # the line would fall
    assert _refusal(x, MEM.measurement_address(0), _i32(0)) == "ERR_WRITE_PROTECTED"

    # with the engine stopped: the first breakpoint of the acceleration line (and of the
    # deceleration floor under it) lowered, seen in a later read, here and on the port
    floor_q24, line_q24 = round(1.9 * (1 << 24)), round(2.0 * (1 << 24))
    x.push(MEM.parameter_address(INDEX["decel_floor_v[0]"]), 0, _i32(floor_q24))
    x.push(MEM.parameter_address(INDEX["accel_line_v[0]"]), 0, _i32(line_q24))
    x.setMta(MEM.parameter_address(INDEX["accel_line_v[0]"]))
    assert struct.unpack("<i", x.fetch(4))[0] == line_q24
    if client is not None:
        assert client.get("accel_line_v[0]")["raw"] == line_q24

    # ... and in the ECU's behaviour: the start (the bench's arm, over XCP) keeps its fuel
    # under the line at low speed, for the weakest pump the schedules accept
    v_d = params.pump_dead_v
    cap_mv = 1000 * (v_d + (2.0 - v_d) / params.schedule_pump_range[0])
    x.setMta(MEM.bench_address(MEM.BENCH_ARM))
    x.download(_i32(1))
    states, top_mv, deadline = set(), 0, time.monotonic() + 25
    while time.monotonic() < deadline and not (Q.RAMP in states and top_mv >= cap_mv - 5):
        states.add(_measure(x, "seq_state"))
        top_mv = max(top_mv, _measure(x, "pump_voltage"))
        time.sleep(0.05)
    assert Q.RAMP in states, states
    assert cap_mv - 5 <= top_mv <= cap_mv + 1, (top_mv, cap_mv)
    x.setMta(MEM.bench_address(MEM.BENCH_STOP))
    x.download(_i32(1))
    if client is not None:
        client.transport.close()
    x.disconnect()
