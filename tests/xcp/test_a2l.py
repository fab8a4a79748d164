"""The A2L: `sil a2l` writes a file pya2ldb (pyXCP's A2L database) reads without an error or a
validator's diagnostic, and it agrees with what the slave answers: every CHARACTERISTIC's and
AXIS_PTS's address uploads its values, every MEASUREMENT's address is the slave's, the
conversions are the Q formats, the EPK, identifiers and events are the slave's."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest

from ecu.service.param_table import BY_NAME, TABLE
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.a2l import SCHEDULES, a2l_name


@pytest.mark.slow
def test_pya2ldb_reads_it_without_a_diagnostic(a2l):
    assert a2l["diagnostics"] == []
    schedules = {c["name"] for c in a2l["characteristics"] if c["type"] == "CURVE"}
    assert schedules == set(SCHEDULES)
    scalars = [s for s in TABLE if s.field not in SCHEDULES]
    assert len(a2l["characteristics"]) == len(scalars) + len(SCHEDULES) + len(MEM.BENCH)
    assert {m["name"] for m in a2l["measurements"]} == {
        m.name for m in MEM.MEASUREMENTS + MEM.LOGBOOK
    }


@pytest.mark.slow
def test_every_characteristic_uploads_the_slaves_values(a2l, rig):
    rig.connect()
    table = rig.boot.table
    for c in a2l["characteristics"]:
        size = 4 * c["points"]
        data = b""
        rig.set_mta(c["address"])
        while len(data) < size:
            res = rig.request(C.Cmd.UPLOAD, min(7, size - len(data)))
            assert res[0] == 0xFF, (c["name"], res)
            data += res[1:]
        values = struct.unpack(f"<{c['points']}i", data)
        if c["name"] in SCHEDULES:
            want = [table.raw(f"{c['name']}[{k}]") for k in range(c["points"])]
            spec = BY_NAME[f"{c['name']}[0]"]
        elif c["name"].startswith("bench_"):
            continue  # commands: what they read is the bench's state (tests/xcp/test_writes)
        else:
            spec = next(s for s in TABLE if a2l_name(s.name) == c["name"])
            want = [table.raw(spec.name)]
        assert list(values) == want, c["name"]
        # the conversion is the Q format, the limits the service port's
        assert c["factor"] == 2.0**-spec.frac_bits and (c["lo"], c["hi"]) == (spec.lo, spec.hi)
    (axis,) = a2l["axis_pts"]
    raw = rig.short_upload(axis["address"], 4)
    assert struct.unpack("<i", raw[1:])[0] * axis["factor"] == 45.0 and axis["points"] == 12


@pytest.mark.slow
def test_measurements_ids_epk_and_events_are_the_slaves(a2l, rig):
    for m in a2l["measurements"]:
        if m["name"].startswith("log_"):
            continue  # the logbook region (tests/xcp/test_logbook_region.py)
        k = MEM.MEAS_INDEX[m["name"]]
        assert m["address"] == MEM.measurement_address(k)
        assert m["type"] == MEM.MEASUREMENTS[k].datatype
        assert m["factor"] in (None, MEM.MEASUREMENTS[k].factor)  # None: a value table
    assert a2l["can"] == [0x700, 0x701]
    rig.connect()
    address, epk = a2l["epk"]
    assert rig.request(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", address)) == b"\xff"
    text = b""
    while len(text) < len(epk):
        text += rig.request(C.Cmd.UPLOAD, min(7, len(epk) - len(text)))[1:]
    assert text.decode() == epk == rig.slave.identification
    for number, (name, _, event, kind, _, cycle, unit, priority) in enumerate(a2l["events"]):
        info = rig.request(C.Cmd.GET_DAQ_EVENT_INFO, 0, event, 0)
        assert (event, kind) == (number, "DAQ")
        assert tuple(info[3:7]) == (len(name), cycle, unit, priority)
    assert a2l["protocol"][8:10] == [8, 8]


def test_a2l_for_another_rate_and_ids(sil, tmp_path):
    path = tmp_path / "x.a2l"
    done = sil("a2l", "--out", str(path), "--rate", "200", "--xcp-ids", "0x600,0x601")
    assert done.returncode == 0, done.stderr
    text = path.read_text(encoding="latin-1")
    assert "CAN_ID_MASTER 0x600" in text and '"control tick" "tick" 0 DAQ 255 5 6 1' in text
    assert sil("a2l", "--xcp-ids", "0x100,0x101").returncode == 2


def test_the_c_slaves_a2l_states_what_the_c_slave_answers(sil, tmp_path):
    """`sil a2l --impl c` (and pil): the master block and the DAQ lists of the C slave, read from
    its header without a compiler, as the compiled slave reports them."""
    from ecu.port.xcp import c_limits, header_limits

    assert header_limits() == c_limits()
    for impl in ("c", "pil"):
        path = tmp_path / f"{impl}.a2l"
        assert sil("a2l", "--impl", impl, "--out", str(path)).returncode == 0
        text = path.read_text(encoding="latin-1")
        assert f"BLOCK MASTER {c_limits().max_bs} 0" in text
        assert f"DYNAMIC {c_limits().max_daq} 2 0" in text
    python = sil("a2l").stdout
    assert "BLOCK MASTER 42 0" in python


@pytest.mark.parametrize("impl", ["python", "c", "pil"])
def test_a2ltool_strict_check_passes_every_a2l_we_write(sil, tmp_path, impl):  # noqa: ANN001
    """a2ltool (the A2L checker calibration tools' users run) parses each A2L strictly and
    finds nothing to report, also at another rate and with other identifiers; it refuses a
    damaged one (a keyword misspelt), so its verdict is a real check."""
    a2ltool = Path(sys.executable).with_name("a2ltool")
    for extra in ([], ["--rate", "200", "--xcp-ids", "0x600,0x601"]):
        path = tmp_path / f"{impl}.a2l"
        assert sil("a2l", "--impl", impl, "--out", str(path), *extra).returncode == 0
        done = subprocess.run([str(a2ltool), str(path), "--check", "--strict"],
                              capture_output=True, text=True, timeout=120)  # fmt: skip
        assert done.returncode == 0 and "No problems found" in done.stdout, done.stdout
    damaged = tmp_path / "damaged.a2l"
    damaged.write_text(path.read_text(encoding="latin-1").replace("READ_ONLY", "READ_ONLYX"),
                       encoding="latin-1")  # fmt: skip
    done = subprocess.run([str(a2ltool), str(damaged), "--check", "--strict"],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode != 0 and "READ_ONLYX" in done.stdout + done.stderr
