"""Bad input over XCP against the sans-IO slave (hypothesis): random frames, every command at
every length, DAQ lists that do not fit, addresses outside the map. The slave answers with
response or error packets only, never raises, counts every refusal, and the ECU's ticks are those
of an ECU with no master."""

from __future__ import annotations

import struct

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ecu.firmware import Ecu
from ecu.xcp import codes as C

COMMANDS = [int(c) for c in C.Cmd]
SETTINGS = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

command_frames = st.builds(
    lambda code, rest: bytes((code,)) + rest,
    st.sampled_from(COMMANDS) | st.integers(0, 255),
    st.binary(max_size=7),
)
frames = st.lists(command_frames | st.binary(max_size=8), max_size=40)


def _outputs(ecu: Ecu) -> tuple[int, ...]:
    o = ecu.out
    return (o.mode, o.pump_mv, o.duty_cpct, o.fault_word, o.nref_cpct, o.owner, o.seq_state)


def _packets_are_answers(sent: list[bytes]) -> None:
    for packet in sent:
        assert packet, "an empty packet"
        assert len(packet) <= 8
        assert packet[0] in (C.PID_RES, C.PID_ERR, C.PID_EV) or packet[0] <= C.PID_DAQ_MAX


@SETTINGS
@given(frames, st.booleans())
def test_random_frames_get_answers_only_and_the_ecu_ticks_as_without_a_master(
    rig_factory, batch, unlock_daq
):
    rig = rig_factory()
    reference = Ecu(rig.boot.table.firmware)
    rig.engine_running()
    rig.connect()
    if unlock_daq:
        rig.unlock(C.RES_DAQ)  # DAQ set-ups may then run; CAL/PAG stays locked: no write lands
    before = rig.slave.counters.errors.copy()
    sent: list[bytes] = []
    for k, frame in enumerate(batch):
        rig.slave.receive(frame)
        if k % 3 == 0:
            sent += rig.tick()
            reference.tick(rig.i)
            assert _outputs(rig.ecu) == _outputs(reference)
    sent += rig.tick()
    reference.tick(rig.i)
    assert _outputs(rig.ecu) == _outputs(reference)
    _packets_are_answers(sent)
    c = rig.slave.counters
    errors = [p for p in sent if p[0] == C.PID_ERR]
    refused = sum(c.errors.values()) - sum(before.values())
    assert refused == len(errors)
    assert c.frames == c.served + c.ignored + c.empty + c.queue_overflow + len(rig.slave._queue)
    assert c.internal_errors == 0  # every refusal was one the slave meant


def test_every_command_at_every_length_is_answered(rig_factory):
    """Each command cut to every length 1..8 (pads of 0x00 and 0xFF): one answer each, an
    error when too short for it (a DOWNLOAD of 0 or 255 bytes begins no master block)."""
    for pad in (0x00, 0xFF):
        rig = rig_factory()
        rig.connect()
        rig.unlock(C.RES_CAL_PAG)
        rig.unlock(C.RES_DAQ)
        for code in COMMANDS:
            if code in (C.Cmd.DISCONNECT, C.Cmd.CONNECT, C.Cmd.UNLOCK):
                continue
            for length in range(1, 9):
                frame = bytes((code,)) + bytes((pad,)) * (length - 1)
                rig.slave.receive(frame)
                out = rig.serve()
                minimum = rig.slave._handlers.get(code, (0,))[0]
                if code not in rig.slave._handlers:
                    assert out == [bytes((C.PID_ERR, C.Err.CMD_UNKNOWN))], hex(code)
                elif length < minimum:
                    assert out == [bytes((C.PID_ERR, C.Err.CMD_SYNTAX))], (hex(code), length)
                else:
                    assert len(out) == 1 and out[0][0] in (C.PID_RES, C.PID_ERR), (code, length)
                rig.tick()
        assert rig.slave.connected


addresses = st.integers(0, 0xFFFF_FFFF) | st.sampled_from(
    [0x0800_0000, 0x0800_1000, 0x2000_0000, 0x2001_0000, 0x2002_0000]
).flatmap(lambda base: st.integers(base - 8, base + 0x400))


@SETTINGS
@given(addresses, st.integers(0, 9))
def test_uploads_answer_data_inside_the_map_and_out_of_range_outside(rig, address, size):
    rig.connect()
    res = rig.short_upload(address, size)
    inside = 1 <= size <= 7 and rig.slave.memory.read(address, size) is not None
    assert res[0] == (C.PID_RES if inside else C.PID_ERR)
    if inside:
        assert len(res) == 1 + size
    else:
        assert res == bytes((C.PID_ERR, C.Err.OUT_OF_RANGE))


@SETTINGS
@given(
    st.lists(st.integers(0, 80), min_size=1, max_size=20),
    st.lists(st.tuples(addresses, st.integers(0, 9)), min_size=1, max_size=30),
)
def test_daq_lists_that_do_not_fit_are_refused_and_what_runs_fits(rig, odts, entries):
    """ODT counts beyond the budget, entries beyond 7 bytes an ODT or outside the map: refused
    with their errors; whatever starts sends DTOs of at most 8 bytes, at most MAX_ODTS a tick."""
    from ecu.xcp import daq as D

    rig.connect()
    rig.unlock(C.RES_DAQ)
    rig.request(C.Cmd.FREE_DAQ)
    rig.request(C.Cmd.ALLOC_DAQ, 0, struct.pack("<H", len(odts)))
    for n, count in enumerate(odts):
        rig.request(C.Cmd.ALLOC_ODT, 0, struct.pack("<H", n), count)
    for n, count in enumerate(odts):
        for j in range(min(count, 3)):
            rig.request(C.Cmd.ALLOC_ODT_ENTRY, 0, struct.pack("<H", n), j, 3)
    for k, (address, size) in enumerate(entries):
        n = k % len(odts)
        rig.request(C.Cmd.SET_DAQ_PTR, 0, struct.pack("<H", n), 0, k % 3)
        res = rig.request(struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, size, 0, address))
        assert res[0] in (C.PID_RES, C.PID_ERR)
        if res[0] == C.PID_RES:
            assert rig.slave.memory.locate(address, size) is not None and 1 <= size <= 7
    for n in range(len(odts)):
        rig.request(struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, n, n % 2, 1, 0))
        rig.request(C.Cmd.START_STOP_DAQ_LIST, 2, struct.pack("<H", n))
    rig.request(C.Cmd.START_STOP_SYNCH, 1)
    assert rig.slave.daq.odts <= D.MAX_ODTS and rig.slave.daq.entries <= D.MAX_ENTRIES
    for _ in range(3):
        dtos = rig.tick()
        assert len(dtos) <= D.MAX_ODTS and all(2 <= len(d) <= 8 for d in dtos)


def test_a_frame_longer_than_a_can_frame_is_served_on_its_command_bytes(rig):
    assert rig.request(bytes((C.Cmd.CONNECT, 0)) + bytes(100))[0] == C.PID_RES
    assert rig.request(bytes((C.Cmd.GET_STATUS,)) + bytes(100))[0] == C.PID_RES


def test_a_fault_inside_the_slave_is_an_error_packet_not_a_crash(rig, monkeypatch):
    rig.connect()

    def broken(frame: bytes) -> bytes:
        raise IndexError("a slave's own bug")

    code = C.Cmd.GET_STATUS
    monkeypatch.setitem(rig.slave._handlers, code, (1, 0, broken))
    assert rig.request(code) == bytes((C.PID_ERR, C.Err.GENERIC))
    assert rig.slave.counters.internal_errors == 1
    rig.tick(2)  # the ECU ticks on
