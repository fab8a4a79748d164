"""Writes over XCP: parameters through the service port's checks (each refusal with its XCP
error), a schedule written whole in a master block, the bench's arm, throttle and stop, and the
store to flash."""

from __future__ import annotations

import struct

import pytest

from ecu import modes as M
from ecu.service import bench_demand as BD
from ecu.service.param_table import BY_NAME, TABLE
from ecu.service.storage import load
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM

OK = b"\xff"
INDEX = {spec.name: k for k, spec in enumerate(TABLE)}


def err(code: int) -> bytes:
    return bytes((C.PID_ERR, code))


def address(name: str) -> int:
    return MEM.parameter_address(INDEX[name])


def i32(*values: int) -> bytes:
    return struct.pack(f"<{len(values)}i", *values)


def raw(rig, name: str) -> int:
    return rig.boot.table.raw(name)


def test_a_write_needs_the_cal_pag_unlock(rig):
    rig.connect()
    assert rig.download(address("egt_limit_k"), i32(1200 << 16)) == err(C.Err.ACCESS_LOCKED)
    rig.unlock(C.RES_CAL_PAG)
    assert rig.download(address("egt_limit_k"), i32(1200 << 16)) == OK
    assert raw(rig, "egt_limit_k") == 1200 << 16
    assert rig.ecu.p.egt_limit_dk == 12000  # applies from the next tick: the firmware's set


def test_each_refusal_has_its_xcp_error(rig):
    rig.connect()
    rig.unlock(C.RES_CAL_PAG)
    before = rig.boot.table.raws()
    # outside its limits [800, 1400] K
    assert rig.download(address("egt_limit_k"), i32(1500 << 16)) == err(C.Err.OUT_OF_RANGE)
    # the set refused as a whole: the acceleration line falls between two breakpoints
    low = raw(rig, "accel_line_v[0]") - (1 << 24)
    assert rig.download(address("accel_line_v[1]"), i32(low)) == err(C.Err.VERIFY)
    # not whole parameters
    assert rig.download(address("egt_limit_k") + 2, i32(0)) == err(C.Err.OUT_OF_RANGE)
    assert rig.download(address("egt_limit_k"), b"\0\0") == err(C.Err.OUT_OF_RANGE)
    # read-only regions and addresses outside the map
    assert rig.download(MEM.MEAS_BASE, i32(0)) == err(C.Err.WRITE_PROTECTED)
    assert rig.download(MEM.AXIS_BASE, i32(0)) == err(C.Err.WRITE_PROTECTED)
    assert rig.download(0x3000_0000, i32(0)) == err(C.Err.OUT_OF_RANGE)
    assert rig.request(C.Cmd.DOWNLOAD, 0) == err(C.Err.OUT_OF_RANGE)
    assert rig.request(C.Cmd.DOWNLOAD, 4, 1, 2) == err(C.Err.CMD_SYNTAX)  # fewer bytes than said
    assert rig.boot.table.raws() == before  # nothing was written


def test_parameters_unsafe_in_run_are_refused_in_run(rig):
    rig.connect()
    rig.unlock(C.RES_CAL_PAG)
    rig.engine_running()
    rig.tick(20)
    assert rig.ecu.out.mode == M.RUN
    assert not BY_NAME["trim_v"].run_safe and BY_NAME["egt_kp"].run_safe
    assert rig.download(address("trim_v"), i32(12 << 24)) == err(C.Err.ACCESS_DENIED)
    assert rig.download(address("egt_kp"), i32(1 << 20)) == OK


def test_a_schedule_is_written_whole_in_one_master_block(rig):
    """The acceleration line raised by 2 V at every point: written point by point, the first
    write would already pass the next point... in one block the set is checked once, whole."""
    rig.connect()
    rig.unlock(C.RES_CAL_PAG)
    names = [f"accel_line_v[{k}]" for k in range(12)]
    new = [raw(rig, n) + (2 << 24) for n in names]
    data = i32(*new)
    assert rig.set_mta(address(names[0])) == OK
    # DOWNLOAD with the block's length, then DOWNLOAD_NEXT with what remains; one answer
    assert rig.request(C.Cmd.DOWNLOAD, len(data), data[:6]) == b""
    at = 6
    while at < len(data):
        answer = rig.request(C.Cmd.DOWNLOAD_NEXT, len(data) - at, data[at : at + 6])
        at += 6
        assert answer == (OK if at >= len(data) else b"")
    assert [raw(rig, n) for n in names] == new
    assert rig.set_mta(address(names[0])) == OK
    assert rig.request(C.Cmd.UPLOAD, 4) == OK + data[:4]


def test_a_master_block_out_of_sequence_is_refused(rig):
    rig.connect()
    rig.unlock(C.RES_CAL_PAG)
    assert rig.set_mta(address("accel_line_v[0]")) == OK
    assert rig.request(C.Cmd.DOWNLOAD, 12, b"\0" * 6) == b""
    assert rig.request(C.Cmd.DOWNLOAD_NEXT, 5, b"\0" * 5) == bytes((0xFE, C.Err.SEQUENCE, 6))
    assert rig.request(C.Cmd.DOWNLOAD_NEXT, 6, b"\0" * 6)[:2] == err(C.Err.SEQUENCE)
    assert rig.request(C.Cmd.DOWNLOAD, 253) == err(C.Err.OUT_OF_RANGE)  # beyond MAX_BS frames


def test_the_bench_arms_throttles_and_stops_over_xcp(rig):
    rig.connect()
    arm, stop, throttle = (MEM.bench_address(k) for k in range(3))
    rig.tick(3)  # no readings yet
    assert rig.download(arm, i32(1)) == err(C.Err.ACCESS_LOCKED)
    rig.unlock(C.RES_CAL_PAG)
    assert rig.download(arm, i32(1)) == err(C.Err.ACCESS_DENIED)  # no valid readings yet
    rig.at_rest()
    rig.tick(3)
    assert rig.download(arm, i32(1)) == OK
    rig.tick(2)
    assert rig.ecu.out.mode == M.ARMED and rig.slave.bench.source == BD.BENCH
    assert rig.download(throttle, i32(7000)) == OK
    rig.tick(2)
    assert rig.ecu.s.demand_q24 == pytest.approx(70 << 24, abs=1 << 10)
    assert rig.download(throttle, i32(13000)) == err(C.Err.OUT_OF_RANGE)
    assert rig.short_upload(throttle, 4) == OK + i32(7000)
    rig.connect()  # a new session: locked, but a stop is always taken
    assert rig.download(stop, i32(1)) == OK
    rig.tick(3)
    assert rig.ecu.out.mode == M.OFF
    assert rig.short_upload(stop, 4) == OK + i32(1)


def test_store_cal_saves_the_set_to_flash_and_says_when_done(rig_factory, tmp_path):
    flash = tmp_path / "flash.bin"
    rig = rig_factory(flash=flash)
    rig.connect()
    assert rig.request(C.Cmd.SET_REQUEST, C.REQUEST_STORE_CAL, 0, 0) == err(C.Err.ACCESS_LOCKED)
    rig.unlock(C.RES_CAL_PAG)
    assert rig.download(address("egt_limit_k"), i32(1210 << 16)) == OK
    assert rig.request(C.Cmd.SET_REQUEST, C.REQUEST_STORE_CAL, 0, 0) == OK
    assert rig.request(C.Cmd.GET_STATUS)[1] & C.SESSION_STORE_CAL_REQ
    assert rig.request(C.Cmd.SET_REQUEST, C.REQUEST_STORE_CAL, 0, 0) == err(C.Err.CMD_BUSY)
    events = []
    for _ in range(40):
        events += [f for f in rig.tick() if f[0] == C.PID_EV]
    assert events == [bytes((C.PID_EV, C.Ev.STORE_CAL))]
    assert not rig.request(C.Cmd.GET_STATUS)[1] & C.SESSION_STORE_CAL_REQ
    rig.boot.flash.close()  # power off
    assert rig_factory(flash=flash).boot.table.raw("egt_limit_k") == 1210 << 16
    assert load(flash).sequence == rig.boot.sequence


def test_store_cal_without_a_flash_image_is_refused(rig):
    rig.connect()
    rig.unlock(C.RES_CAL_PAG)
    assert rig.request(C.Cmd.SET_REQUEST, C.REQUEST_STORE_CAL, 0, 0) == err(C.Err.ACCESS_DENIED)
    assert rig.request(C.Cmd.SET_REQUEST, C.REQUEST_CLEAR_DAQ, 0, 0) == err(C.Err.OUT_OF_RANGE)
