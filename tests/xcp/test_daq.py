"""Dynamic DAQ lists over the slave: allocated, written, started and sampled on the control tick
and the 100 ms event, with timestamps; the configurations it refuses."""

from __future__ import annotations

import struct

from ecu.xcp import codes as C
from ecu.xcp import daq as D
from ecu.xcp import memory as MEM

OK = b"\xff"


def err(code: int) -> bytes:
    return bytes((C.PID_ERR, code))


def u16(x: int) -> bytes:
    return struct.pack("<H", x)


def meas(name: str) -> int:
    return MEM.measurement_address(MEM.MEAS_INDEX[name])


def configure(rig, lists: list[tuple[int, int, list[list[tuple[int, int]]]]]) -> list[int]:
    """Program DAQ lists as pyXCP does: (event, prescaler, ODTs of (address, size) entries);
    selected, then started together. Returns each list's FIRST_PID."""
    assert rig.request(C.Cmd.FREE_DAQ) == OK
    assert rig.request(C.Cmd.ALLOC_DAQ, 0, u16(len(lists))) == OK
    for n, (_, _, odts) in enumerate(lists):
        assert rig.request(C.Cmd.ALLOC_ODT, 0, u16(n), len(odts)) == OK
    for n, (_, _, odts) in enumerate(lists):
        for j, odt in enumerate(odts):
            assert rig.request(C.Cmd.ALLOC_ODT_ENTRY, 0, u16(n), j, len(odt)) == OK
    for n, (_, _, odts) in enumerate(lists):
        for j, odt in enumerate(odts):
            if not odt:
                continue
            assert rig.request(C.Cmd.SET_DAQ_PTR, 0, u16(n), j, 0) == OK
            for address, size in odt:
                frame = struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, size, 0, address)
                assert rig.request(frame) == OK
    pids = []
    for n, (event, prescaler, _) in enumerate(lists):
        mode = struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, n, event, prescaler, 0)
        assert rig.request(mode) == OK
        res = rig.request(C.Cmd.START_STOP_DAQ_LIST, 2, u16(n))
        assert res[0] == 0xFF
        pids.append(res[1])
    assert rig.request(C.Cmd.START_STOP_SYNCH, 1) == OK
    return pids


def test_processor_resolution_and_events_describe_the_slave(rig):
    rig.connect()
    assert rig.request(C.Cmd.GET_DAQ_PROCESSOR_INFO) == bytes(
        (0xFF, 0x13, D.MAX_DAQ, 0, 2, 0, 0, 0)
    )
    # byte granularity, at most 7 bytes an entry, no STIM, 4-byte fixed timestamps of 1 us
    assert rig.request(C.Cmd.GET_DAQ_RESOLUTION_INFO) == bytes((0xFF, 1, 7, 1, 0, 0x3C, 1, 0))
    info = rig.request(C.Cmd.GET_DAQ_EVENT_INFO, 0, u16(0))
    assert info == bytes((0xFF, 0x84, 0xFF, len("control tick"), 10, C.UNIT_1MS, 1))
    assert rig.request(C.Cmd.UPLOAD, 7) == OK + b"control"
    info = rig.request(C.Cmd.GET_DAQ_EVENT_INFO, 0, u16(1))
    assert info[3:6] == bytes((len("100 ms"), 100, C.UNIT_1MS))
    assert rig.request(C.Cmd.GET_DAQ_EVENT_INFO, 0, u16(2)) == err(C.Err.OUT_OF_RANGE)


def test_a_list_on_the_control_tick_samples_every_tick_with_its_timestamp(rig):
    rig.connect()
    rig.unlock(C.RES_DAQ)
    rig.at_rest()
    # ODT 0: the timestamp and 3 bytes; then the tick count's last byte and the EGT (a SWORD)
    odts = [[(meas("ticks"), 3)], [(meas("ticks") + 3, 1), (meas("egt"), 2)]]
    (first,) = configure(rig, [(0, 1, odts)])
    assert rig.request(C.Cmd.GET_STATUS)[1] & C.SESSION_DAQ_RUNNING
    for k in range(1, 6):
        dtos = rig.tick()
        assert [d[0] for d in dtos] == [first, first + 1]
        (stamp,) = struct.unpack_from("<I", dtos[0], 1)
        assert stamp == k * 10_000  # the ECU's time after tick k, in us (100 Hz)
        ticks = int.from_bytes(dtos[0][5:8] + dtos[1][1:2], "little")
        (egt,) = struct.unpack_from("<h", dtos[1], 2)
        assert (ticks, egt) == (k, 2_900)
    res = rig.request(C.Cmd.GET_DAQ_CLOCK)
    assert res[:4] == bytes((0xFF, 0, 0, 0)) and struct.unpack_from("<I", res, 4)[0] == 50_000


def test_the_100_ms_event_and_the_prescaler(rig):
    rig.connect()
    rig.unlock(C.RES_DAQ)
    lists = [(1, 1, [[(meas("ticks"), 3)]]), (0, 4, [[(meas("mode"), 1)]])]
    slow, fast = configure(rig, lists)
    seen = {slow: [], fast: []}
    for _ in range(40):
        for dto in rig.tick():
            seen[dto[0]].append(int.from_bytes(dto[5:8], "little"))
    assert seen[slow] == [1, 11, 21, 31]  # every 10 ticks, from the first
    assert len(seen[fast]) == 10  # every 4th tick


def test_configurations_that_do_not_fit_are_refused(rig):
    rig.connect()
    rig.unlock(C.RES_DAQ)
    assert rig.request(C.Cmd.ALLOC_ODT, 0, u16(0), 1) == err(C.Err.SEQUENCE)  # before ALLOC_DAQ
    assert rig.request(C.Cmd.ALLOC_DAQ, 0, u16(D.MAX_DAQ + 1)) == err(C.Err.MEMORY_OVERFLOW)
    assert rig.request(C.Cmd.ALLOC_DAQ, 0, u16(2)) == OK
    assert rig.request(C.Cmd.ALLOC_DAQ, 0, u16(2)) == err(C.Err.SEQUENCE)
    assert rig.request(C.Cmd.ALLOC_ODT, 0, u16(2), 1) == err(C.Err.OUT_OF_RANGE)
    assert rig.request(C.Cmd.ALLOC_ODT, 0, u16(0), D.MAX_ODTS + 1) == err(C.Err.MEMORY_OVERFLOW)
    assert rig.request(C.Cmd.ALLOC_ODT, 0, u16(0), 2) == OK
    assert rig.request(C.Cmd.ALLOC_ODT_ENTRY, 0, u16(0), 0, 8) == err(C.Err.MEMORY_OVERFLOW)
    assert rig.request(C.Cmd.ALLOC_ODT_ENTRY, 0, u16(0), 0, 2) == OK
    assert rig.request(C.Cmd.ALLOC_ODT, 0, u16(1), 1) == err(C.Err.SEQUENCE)  # after entries
    assert rig.request(C.Cmd.ALLOC_ODT_ENTRY, 0, u16(0), 1, 2) == OK
    assert rig.request(C.Cmd.SET_DAQ_PTR, 0, u16(0), 0, 2) == err(C.Err.OUT_OF_RANGE)
    assert rig.request(C.Cmd.SET_DAQ_PTR, 0, u16(0), 0, 0) == OK

    def write(size: int, address: int, bit: int = 0xFF) -> bytes:
        return rig.request(struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, bit, size, 0, address))

    assert write(4, 0x1000_0000) == err(C.Err.OUT_OF_RANGE)  # not in the map
    assert write(8, meas("ticks")) == err(C.Err.OUT_OF_RANGE)  # more than an entry holds
    assert write(1, meas("ticks"), bit=3) == err(C.Err.OUT_OF_RANGE)  # no bit entries
    assert write(4, meas("ticks")) == OK
    assert write(4, meas("mode")) == err(C.Err.DAQ_CONFIG)  # 8 bytes in one ODT
    assert write(3, meas("mode")) == OK  # 7 bytes: but no room for the timestamp in ODT 0
    mode = struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 1, 0)
    assert rig.request(mode) == OK
    assert rig.request(C.Cmd.START_STOP_DAQ_LIST, 1, u16(0)) == err(C.Err.DAQ_CONFIG)
    bad_event = struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 2, 1, 0)
    assert rig.request(bad_event) == err(C.Err.OUT_OF_RANGE)
    stim = struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x02, 0, 0, 1, 0)
    assert rig.request(stim) == err(C.Err.OUT_OF_RANGE)
    assert rig.request(C.Cmd.START_STOP_DAQ_LIST, 1, u16(1)) == err(C.Err.DAQ_CONFIG)  # no ODTs
    assert rig.request(C.Cmd.START_STOP_SYNCH, 7) == err(C.Err.OUT_OF_RANGE)
    assert rig.tick(3) == []  # nothing started


def test_disconnect_stops_and_frees_the_lists(rig):
    rig.connect()
    rig.unlock(C.RES_DAQ)
    configure(rig, [(0, 1, [[(meas("ticks"), 3)]])])
    assert len(rig.tick()) == 1
    assert rig.request(C.Cmd.DISCONNECT) == OK
    assert rig.tick(3) == []
    rig.connect()
    assert rig.request(C.Cmd.GET_DAQ_LIST_MODE, 0, u16(0)) == err(C.Err.OUT_OF_RANGE)
