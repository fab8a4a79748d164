"""The logbook region over XCP: the Python and the C slave upload the firmware's logbook words
at the A2L's addresses (SHORT_UPLOAD, UPLOAD), the region is read only, and the A2L (both
implementations) lists the logbook's MEASUREMENTs with their conversions."""

from __future__ import annotations

import struct

import pytest

from ecu import logbook as L
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from tests.xcp.conftest import read_a2l
from tests.xcp.test_c_slave import Rigs

NAMES = (
    "log_runs", "log_run_time_s", "log_starts",
    *(f"log_aborts_{r.lower()}" for r in ("IGNITION_TIMEOUT", "SLOW_ACCEL", "STARTER_FAILURE",
                                          "HOT_START", "FLAMEOUT", "STOPPED")),
    "log_last_max_egt", "log_last_max_speed", "log_last_shutdown",
)  # fmt: skip


def _fill(s: object, base: int) -> list[int]:
    """Distinct values in every stored word of a state; returns them in stored order."""
    values = [base + 7 * k for k in range(len(L.word_names()))]
    values[-1] = L.SD_START_ABORT  # log_last_shutdown: a reason
    words = iter(values)
    for name in L.STORED:
        if name == "log_aborts":
            for k in range(L.N_ABORTS):
                s.log_aborts[k] = next(words)
        else:
            setattr(s, name, next(words))
    return values


def test_both_slaves_upload_the_logbook_as_the_firmware_holds_it():
    rigs = Rigs()
    rigs.same(C.Cmd.CONNECT, 0)
    for k in range(3):
        rigs.tick()
        values = _fill(rigs.py_ecu.s, 1000 * (k + 1))
        assert _fill(rigs.c_ecu.s, 1000 * (k + 1)) == values
        for index, word in enumerate(values):
            address = MEM.logbook_address(index)
            res = rigs.same(C.Cmd.SHORT_UPLOAD, 4, 0, 0, struct.pack("<I", address))
            assert res[0] == C.PID_RES and struct.unpack("<i", res[1:5])[0] == word
        # the whole region by UPLOAD from its base
        rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", MEM.LOG_BASE))
        data = b""
        while len(data) < 4 * len(values):
            data += rigs.same(C.Cmd.UPLOAD, min(7, 4 * len(values) - len(data)))[1:]
        assert list(struct.unpack(f"<{len(values)}i", data)) == values


def test_the_logbook_follows_the_ticks_and_is_read_only():
    rigs = Rigs()
    rigs.same(C.Cmd.CONNECT, 0)
    rigs.set_inputs(sensor_status=0, analog_status=0, speed_rpm=0, egt_dk=2900, supply_mv=22200)
    rigs.set_inputs(demand_status=0, demand_cpct=3500, arm=1)
    rigs.ticks(5)  # OFF -> ARMED: a start
    assert rigs.py_ecu.s.log_starts == rigs.c_ecu.s.log_starts == 1
    starts = MEM.logbook_address(L.word_names().index("log_starts"))
    res = rigs.same(C.Cmd.SHORT_UPLOAD, 4, 0, 0, struct.pack("<I", starts))
    assert struct.unpack("<i", res[1:5])[0] == 1
    # a write to the region is refused, alike
    rigs.same(C.Cmd.SET_MTA, 0, 0, 0, struct.pack("<I", starts))
    refused = rigs.same(C.Cmd.DOWNLOAD, 4, struct.pack("<i", 0))
    assert refused[0] == C.PID_ERR
    assert rigs.py_ecu.s.log_starts == rigs.c_ecu.s.log_starts == 1


@pytest.mark.slow
@pytest.mark.parametrize("impl", ["python", "c"])
def test_the_a2l_lists_the_logbook(impl, sil, tmp_path):
    path = tmp_path / f"{impl}.a2l"
    done = sil("a2l", "--impl", impl, "--out", str(path))
    assert done.returncode == 0, done.stderr
    a2l = read_a2l(path)
    found = {m["name"]: m for m in a2l["measurements"] if m["name"].startswith("log_")}
    assert set(NAMES) <= set(found)
    for k, m in enumerate(MEM.LOGBOOK):
        assert found[m.name]["address"] == MEM.logbook_address(k)
        assert found[m.name]["type"] == "SLONG"
    assert found["log_last_max_egt"]["factor"] == 0.1
    assert found["log_last_max_speed"]["factor"] == 0.01
    assert found["log_last_shutdown"]["factor"] is None  # a value table
    text = path.read_text()
    assert "VT_log_last_shutdown" in text
    for k, name in enumerate(L.SHUTDOWN_NAMES):
        assert f'{k} "{name}"' in text
