"""The XCP slave's command processor, frame by frame (sans-IO): session, identification,
protection, uploads and checksums, the error packets of what it refuses."""

from __future__ import annotations

import struct

from ecu.service.crc import crc16
from ecu.service.message import unlock_key
from ecu.service.param_table import TABLE
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp.seed_key import key_for
from ecu.xcp.slave import A2L_NAME, MAX_BS

OK = b"\xff"


def err(code: int) -> bytes:
    return bytes((C.PID_ERR, code))


def test_connect_gives_the_resources_and_the_sizes(rig):
    res = rig.connect()
    assert res == bytes((0xFF, C.RES_CAL_PAG | C.RES_DAQ, 0x80, 8, 8, 0, 1, 1))
    assert rig.request(C.Cmd.GET_COMM_MODE_INFO) == bytes((0xFF, 0, 1, 0, MAX_BS, 0, 0, 0x10))
    # locked CAL/PAG and DAQ, no store under way, DAQ not running
    assert rig.request(C.Cmd.GET_STATUS) == bytes((0xFF, 0, 0x05, 0, 0, 0))
    assert rig.request(C.Cmd.SYNCH) == err(C.Err.CMD_SYNCH)
    assert rig.request(C.Cmd.DISCONNECT) == OK


def test_a_slave_not_connected_answers_connect_only(rig):
    assert rig.request(C.Cmd.GET_STATUS) == b""
    assert rig.request(C.Cmd.SHORT_UPLOAD, 4, 0, 0, 0, 0, 0, 0x20) == b""
    assert rig.slave.counters.ignored == 2
    rig.connect()
    rig.request(C.Cmd.DISCONNECT)
    assert rig.request(C.Cmd.GET_STATUS) == b""


def test_unknown_commands_and_short_frames_get_their_errors(rig):
    rig.connect()
    assert rig.request(0xC0, 0x00) == err(C.Err.CMD_UNKNOWN)  # GET_VERSION: not spoken
    assert rig.request(0x01) == err(C.Err.CMD_UNKNOWN)
    assert rig.request(C.Cmd.SET_MTA, 0, 0, 0, 0x20) == err(C.Err.CMD_SYNTAX)
    assert rig.request(C.Cmd.GET_ID) == err(C.Err.CMD_SYNTAX)
    assert rig.request(b"") == b""
    c = rig.slave.counters
    assert c.errors == {"CMD_UNKNOWN": 2, "CMD_SYNTAX": 2} and c.empty == 1


def _get_id(rig, kind: int) -> str:
    res = rig.request(C.Cmd.GET_ID, kind)
    assert res[:4] == bytes((0xFF, 0, 0, 0))  # mode 0: upload it from the MTA
    length = struct.unpack_from("<I", res, 4)[0]
    text = b""
    while len(text) < length:
        part = rig.request(C.Cmd.UPLOAD, min(7, length - len(text)))
        assert part[0] == 0xFF
        text += part[1:]
    return text.decode("ascii")


def test_get_id_gives_the_identification_and_the_a2l_name_by_upload(rig):
    rig.connect()
    assert _get_id(rig, C.ID_ASCII).startswith("turbojet-ecu 0.1 build ")
    assert _get_id(rig, C.ID_A2L_NAME) == A2L_NAME
    assert _get_id(rig, C.ID_A2L_FILE) == f"{A2L_NAME}.a2l"
    assert _get_id(rig, 3) == ""  # no URL: length 0


def test_every_parameter_uploads_as_its_raw_q_integer(rig):
    rig.connect()
    for k, spec in enumerate(TABLE):
        res = rig.short_upload(MEM.parameter_address(k), 4)
        assert res[0] == 0xFF and struct.unpack("<i", res[1:])[0] == rig.boot.table.raw(spec.name)


def test_measurements_follow_the_ticks(rig):
    rig.connect()
    rig.at_rest()
    rig.tick(3)
    ticks = rig.short_upload(MEM.measurement_address(MEM.MEAS_INDEX["ticks"]), 4)
    egt = rig.short_upload(MEM.measurement_address(MEM.MEAS_INDEX["egt"]), 2)  # a SWORD
    assert struct.unpack("<i", ticks[1:])[0] == 3 and struct.unpack("<h", egt[1:])[0] == 2_900


def test_uploads_outside_the_map_or_too_long_are_refused(rig):
    rig.connect()
    assert rig.short_upload(0x1000_0000, 4) == err(C.Err.OUT_OF_RANGE)
    last = MEM.parameter_address(len(TABLE) - 1)
    assert rig.short_upload(last + 2, 4) == err(C.Err.OUT_OF_RANGE)  # across the region's end
    assert rig.short_upload(MEM.CAL_BASE, 8) == err(C.Err.OUT_OF_RANGE)  # more than 7
    assert rig.request(C.Cmd.UPLOAD, 0) == err(C.Err.OUT_OF_RANGE)
    assert rig.request(C.Cmd.SHORT_UPLOAD, 4, 0, 1, 0, 0, 0, 0x20) == err(C.Err.OUT_OF_RANGE)


def test_build_checksum_is_crc16_ccitt_over_the_block(rig):
    rig.connect()
    rig.set_mta(MEM.CAL_BASE)
    size = 4 * len(TABLE)
    res = rig.request(C.Cmd.BUILD_CHECKSUM, 0, 0, 0, struct.pack("<I", size))
    kind, _, value = struct.unpack_from("<BHI", res, 1)
    raws = struct.pack(f"<{len(TABLE)}i", *rig.boot.table.raws())
    assert res[0] == 0xFF and kind == C.CHECKSUM_CRC_16_CITT and value == crc16(raws)
    too_big = rig.request(C.Cmd.BUILD_CHECKSUM, 0, 0, 0, struct.pack("<I", 1 << 20))
    assert too_big[:2] == err(C.Err.OUT_OF_RANGE) and struct.unpack_from("<I", too_big, 4)[0]


def test_the_key_is_the_service_ports_unlock_as_bytes():
    seed = bytes((0x12, 0x34, 0x56, 0x78))
    assert key_for(seed) == unlock_key(0x12345678).to_bytes(2, "big")


def test_seed_and_key_unlock_each_resource(rig):
    rig.connect()
    assert rig.unlock(C.RES_CAL_PAG) == bytes((0xFF, C.RES_DAQ))
    assert rig.request(C.Cmd.GET_SEED, 0, C.RES_CAL_PAG) == bytes((0xFF, 0))  # unlocked: no seed
    assert rig.unlock(C.RES_DAQ) == bytes((0xFF, 0))
    assert rig.request(C.Cmd.GET_SEED, 0, 0x05) == err(C.Err.OUT_OF_RANGE)  # one at a time
    assert rig.request(C.Cmd.UNLOCK, 2, 0, 0) == err(C.Err.SEQUENCE)  # no seed asked for
    rig.connect()  # a new session is locked again
    assert rig.request(C.Cmd.GET_STATUS)[2] == C.RES_CAL_PAG | C.RES_DAQ


def test_a_wrong_key_ends_the_session(rig):
    rig.connect()
    seed = rig.request(C.Cmd.GET_SEED, 0, C.RES_CAL_PAG)[2:6]
    wrong = bytes(b ^ 0xFF for b in key_for(seed))
    assert rig.request(C.Cmd.UNLOCK, 2, wrong) == err(C.Err.ACCESS_LOCKED)
    assert rig.request(C.Cmd.GET_STATUS) == b""  # disconnected
    rig.connect()
    seed = rig.request(C.Cmd.GET_SEED, 0, C.RES_DAQ)[2:6]
    assert rig.request(C.Cmd.UNLOCK, 4, key_for(seed), b"\0\0") == err(C.Err.ACCESS_LOCKED)


def test_daq_configuration_needs_the_daq_unlock(rig):
    rig.connect()
    assert rig.request(C.Cmd.FREE_DAQ) == err(C.Err.ACCESS_LOCKED)
    assert rig.request(C.Cmd.GET_DAQ_PROCESSOR_INFO)[0] == 0xFF  # information is open
    rig.unlock(C.RES_DAQ)
    assert rig.request(C.Cmd.FREE_DAQ) == OK


def test_a_burst_of_frames_is_bounded_per_tick_and_counted(rig):
    rig.connect()
    for _ in range(200):
        rig.slave.receive(bytes((C.Cmd.GET_STATUS,)))
    served = rig.serve()
    assert len(served) == 48  # MAX_FRAMES a tick
    assert rig.slave.counters.queue_overflow == 200 - 64  # MAX_QUEUE waiting
    assert len(rig.serve()) == 64 - 48


def test_a_measurement_outside_its_type_is_saturated_not_a_crash(rig):
    rig.connect()
    rig.at_rest()
    rig.tick()
    rig.ecu.s.egt_dk = 10**6  # beyond the SWORD it is measured in
    rig.ecu.s.ticks += 1  # a new tick's image
    res = rig.short_upload(MEM.measurement_address(MEM.MEAS_INDEX["egt"]), 2)
    assert struct.unpack("<h", res[1:])[0] == 32767
