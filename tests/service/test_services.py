"""Every service over loop:// against independent expectations; bad input is counted, never
fatal; the port's work per tick is bounded."""

import socket
import time

import crcmod.predefined
import msgpack
import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from ecu import faults as F
from ecu import modes as M
from ecu.firmware import Ecu, EcuInputs
from ecu.firmware_params import compile_params
from ecu.params import EcuParams
from ecu.service import fault_log, live
from ecu.service.framing import MAX_ENCODED, encode_frame
from ecu.service.message import Kind, Message, Service, Status, pack, unpack
from ecu.service.param_table import TABLE
from ecu.service.port import (
    COUNTER_NAMES,
    MAX_REQUESTS,
    MAX_RX_BYTES,
    PENDING_MAX,
    ServicePort,
    boot,
)
from ecu.service.transport import open_transport
from sil.console.client import ServiceClient, ServiceRequestError
from tests.service.conftest import LoopRig

CRC = crcmod.predefined.mkCrcFun("crc-ccitt-false")


def _expected_set_crc(p: EcuParams) -> int:
    """The stored set's CRC computed from the parameter record itself."""
    values = {}
    for spec in TABLE:
        v = getattr(p, spec.field)
        v = v if spec.element is None else v[spec.element]
        values[spec.name] = round(float(v) * 2**spec.frac_bits)
    return CRC(msgpack.packb(values))


def test_identify(rig):
    ident = rig.client.identify()
    assert ident["firmware"].startswith("turbojet-ecu")
    assert len(ident["build"]) == 12 and ident["protocol"] == 1
    assert ident["param_crc"] == _expected_set_crc(EcuParams())
    assert (ident["params"], ident["rate_hz"], ident["storage"]) == (len(TABLE), 100, "none")


def test_read_parameters_with_q_format_units_and_limits(rig):
    assert rig.client.get("pid_kp") == {"name": "pid_kp", "raw": 2 << 24, "frac": 24, "value": 2.0}
    egt = rig.client.get("egt_limit_k")
    assert (egt["raw"], egt["frac"]) == (1280 << 16, 16)
    table = {p["name"]: p for p in rig.client.params()}
    assert len(table) == len(TABLE)
    assert table["gamma_x[1]"]["value"] == pytest.approx(0.1, abs=2**-24)
    assert (table["trim_v"]["unit"], table["trim_v"]["run_safe"]) == ("V", False)
    assert (table["trim_v"]["min"], table["trim_v"]["max"]) == (1.0, 25.0)
    with pytest.raises(ServiceRequestError, match="UNKNOWN_PARAM: unknown parameter 'nope'"):
        rig.client.get("nope")


def test_write_needs_the_unlock_and_is_range_checked(rig):
    c = rig.client
    with pytest.raises(ServiceRequestError, match="LOCKED"):
        c.request(Service.PARAM_WRITE, {"name": "pid_kp", "raw": 3 << 24})
    seed = c.request(Service.UNLOCK_SEED)["seed"]
    with pytest.raises(ServiceRequestError, match="BAD_KEY"):
        c.request(Service.UNLOCK_KEY, {"key": (CRC(seed.to_bytes(4, "big")) + 1) & 0xFFFF})
    with pytest.raises(ServiceRequestError, match="BAD_REQUEST: ask for a seed first"):
        c.request(Service.UNLOCK_KEY, {"key": 0})
    with pytest.raises(
        ServiceRequestError, match=r"OUT_OF_RANGE: pid_kp=25 V/%N: outside .*\[0, 20\]"
    ):
        c.set("pid_kp", 25.0)
    with pytest.raises(ServiceRequestError, match="INVALID: v_max: .*trim_v"):
        c.set("v_max", 10.0)  # below the trim voltage 12.41 V: the set's own check names it
    with pytest.raises(ServiceRequestError, match="BAD_REQUEST: field 'raw' must be a int"):
        c.request(Service.PARAM_WRITE, {"name": "pid_kp", "raw": 1.5})
    r = c.set("pid_kp", 3.25)
    assert r["raw"] == round(3.25 * 2**24) and r["param_crc"] == c.identify()["param_crc"]
    expected = compile_params(EcuParams(pid_kp=3.25))
    assert rig.ecu.p.pid_kp_q24 == expected.pid_kp_q24  # the firmware runs with it
    assert c.identify()["param_crc"] == _expected_set_crc(EcuParams(pid_kp=3.25))


def test_a_fuel_schedule_breakpoint_is_written_and_checked_with_its_table(rig):
    c = rig.client
    c.unlock()
    with pytest.raises(ServiceRequestError, match=r"INVALID: accel_line_v\[3\]: .*must not fall"):
        c.set("accel_line_v[3]", 12.0)  # above the next breakpoint (10.31 V)
    with pytest.raises(
        ServiceRequestError, match=r"INVALID: decel_floor_v\[11\]: .*under accel_line_v"
    ):
        c.set("decel_floor_v[11]", 18.5)  # above the acceleration line there (18.18 V)
    assert c.set("accel_line_v[3]", 9.5)["value"] == pytest.approx(9.5)
    assert rig.ecu.p.accel_line_q24[3] == round(9.5 * 2**24)  # the firmware flies it


def test_unsafe_parameters_are_refused_in_run(rig):
    rig.engine_running()
    rig.ticks(3)
    assert rig.ecu.out.mode == M.RUN
    with pytest.raises(ServiceRequestError, match="REFUSED_IN_RUN: trim_v: unsafe"):
        rig.client.set("trim_v", 12.0)
    assert rig.client.set("egt_limit_k", 1250.0)["value"] == 1250.0  # run-safe
    assert rig.ecu.p.egt_limit_dk == 12500


def test_stream_at_50_hz_decodes_to_the_ecu_outputs(rig):
    rig.engine_running()
    answer = rig.client.stream(50)
    assert answer == {"rate_hz": 50.0, "every": 2, "fields": len(live.FIELDS)}
    rig.client.samples.clear()
    for _ in range(100):
        rig.tick()
        rig.client.receive()
    assert len(rig.client.samples) == 50 and rig.client.stream_gaps == 0
    last = rig.client.latest()
    o = rig.ecu.out
    # the sample of a poll describes the tick before it
    assert last["mode"] == M.RUN and last["speed_rpm"] == 100_890
    assert last["lambda"] == pytest.approx(o.lambda_q24 / 2**24, abs=1e-5)
    assert last["egt"] == pytest.approx(1048.0)
    rig.client.stream(0)
    rig.client.samples.clear()
    rig.ticks(10)
    rig.client.receive()
    assert not rig.client.samples
    with pytest.raises(ServiceRequestError, match="OUT_OF_RANGE: rate_hz=500"):
        rig.client.stream(500)


def test_fault_log_read_and_clear(rig):
    rig.ticks(2)  # no sensor frames: SENSOR_FRAME_LOST rises
    rig.engine_running()
    rig.i.speed_rpm = 200_000  # out of range, persistent: SPEED_RANGE
    rig.ticks(10)
    entries = rig.client.faults()
    names = [e["name"] for e in entries]
    assert names[0] == "SENSOR_FRAME_LOST" and "SPEED_RANGE" in names
    hit = entries[names.index("SPEED_RANGE")]
    assert hit["snapshot"]["fault_word"] & F.SPEED_RANGE
    assert hit["time_s"] > 0 and set(hit["snapshot"]) == set(fault_log.SNAPSHOT_FIELDS)
    with pytest.raises(ServiceRequestError, match="LOCKED"):
        rig.client.request(Service.FAULT_LOG_CLEAR)
    assert rig.client.clear_faults() == len(entries)
    assert rig.client.faults() == []


def test_stop_holds_until_arm(rig):
    rig.engine_running()
    rig.ticks(2)
    assert rig.ecu.out.mode == M.RUN
    rig.client.stop()
    rig.ticks(300)  # the demand frames keep asking for arm and no stop
    assert rig.ecu.out.mode == M.SHUTDOWN
    rig.i.speed_rpm = 5_000  # spooled down
    rig.i.egt_dk = 3_000  # and cool: the sequencer's soak time passes without a cool-down
    rig.i.arm = 0  # the arm switch released: SHUTDOWN -> OFF
    rig.ticks(round(rig.ecu.p.seq_soak_ticks) + 5)
    assert rig.ecu.out.mode == M.OFF
    rig.i.arm = 1  # armed again by the demand frames: the held stop keeps the ECU in OFF
    rig.ticks(50)
    assert rig.ecu.out.mode == M.OFF
    with pytest.raises(ServiceRequestError, match="LOCKED: arming"):
        rig.client.request(Service.ARM)
    rig.client.arm()
    rig.i.stop = 0  # the next demand frame's own stop bit (the held stop had set the input)
    rig.ticks(2)
    assert rig.ecu.out.mode == M.ARMED  # armed, waiting for the starter


def test_bad_frames_are_counted_and_the_port_keeps_answering(rig):
    t = rig.transport
    payload = pack(Message(Kind.REQUEST, 9, Service.IDENTIFY))
    bad_crc = b"\x00" + cobs.encode(payload + ((CRC(payload) ^ 1).to_bytes(2, "big"))) + b"\x00"
    t.write(bad_crc + b"\x00\x05\x00" + b"\x11" * (MAX_ENCODED + 5) + b"\x00")
    t.write(encode_frame(b"\x01\x01"))  # shorter than a header
    t.write(encode_frame(pack(Message(Kind.RESPONSE, 1, Service.IDENTIFY))))  # not a request
    t.write(encode_frame(pack(Message(Kind.REQUEST, 3, Service.IDENTIFY, version=9))))
    t.write(encode_frame(pack(Message(Kind.REQUEST, 4, 0x7F))))
    replies = []
    for _ in range(4):
        rig.tick()
        replies += [unpack(p) for p in rig.client.decoder.feed(t.read(4096))]
    assert [(m.seq, m.status) for m in replies] == [
        (3, Status.BAD_VERSION),
        (4, Status.UNKNOWN_SERVICE),
    ]
    counters = rig.client.counters()
    assert (counters["crc_errors"], counters["malformed"], counters["oversized"]) == (1, 1, 1)
    assert (counters["bad_messages"], counters["unexpected"]) == (1, 1)


def test_work_per_tick_is_bounded(rig):
    frame = encode_frame(pack(Message(Kind.REQUEST, 1, Service.IDENTIFY)))
    burst = frame * 60
    rig.transport.write(burst)
    rig.port.poll(rig.i)
    c = rig.port.counters
    assert c.rx_bytes == MAX_RX_BYTES
    assert c.requests == MAX_REQUESTS
    decoded = MAX_RX_BYTES // len(frame)
    assert len(rig.port._pending) == min(PENDING_MAX, decoded) - MAX_REQUESTS
    assert c.queue_overflow == max(0, decoded - PENDING_MAX)
    assert rig.port.counters.worst_s < 0.05


def test_counters_fit_a_frame_at_any_count(rig):
    c = rig.port.counters
    c.rx_bytes = c.tx_bytes = c.requests = c.polls = c.stream_samples = 2**40
    c.worst_s = c.worst_cpu_s = c.total_s = c.total_cpu_s = 1.234567
    got = rig.client.counters()
    assert got["rx_bytes"] >= 2**40 and got["worst_cpu_us"] == 1234567.0
    assert list(got) == list(COUNTER_NAMES)


bodies = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=6,
)
field_names = st.sampled_from(["name", "raw", "index", "rate_hz", "start", "key", "x"])
long_names = st.fixed_dictionaries({"name": st.text(min_size=100, max_size=240), "raw": bodies})


@settings(max_examples=400, deadline=None, derandomize=True)
@given(
    st.sampled_from([*Service, 0x00, 0x7F, 0xFF]),
    st.one_of(bodies, st.dictionaries(field_names, bodies, max_size=3), long_names),
    st.integers(0, 255),
)
def test_any_request_body_gets_an_answer_and_never_raises(service, body, version):
    rig = LoopRig(EcuParams())
    rig.client.unlock()
    try:
        payload = pack(Message(Kind.REQUEST, 77, service, Status.OK, body, version=version))
    except ValueError:
        return  # larger than a frame: the sender cannot even build it
    rig.transport.write(encode_frame(payload))
    answers = []
    for _ in range(8):  # a save takes a few ticks
        rig.tick()
        answers += [unpack(p) for p in rig.client.decoder.feed(rig.transport.read(4096))]
    replies = [m for m in answers if m.kind == Kind.RESPONSE and m.seq == 77]
    assert len(replies) == 1
    reply = replies[0]
    assert reply.status in Status._value2member_map_
    if reply.status != Status.OK:
        assert isinstance(reply.body["error"], str) and reply.body["error"]


class _SocketEnd:
    """The host's end of a TCP connection as a transport (non-blocking)."""

    name = "tcp"

    def __init__(self, sock: socket.socket) -> None:
        sock.setblocking(False)
        self.sock = sock

    def read(self, max_bytes: int) -> bytes:
        try:
            return self.sock.recv(max_bytes)
        except BlockingIOError:
            return b""

    def write(self, data: bytes) -> int:
        try:
            return self.sock.send(data)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        self.sock.close()


def test_round_trip_over_a_socket_url():
    """The ECU on pyserial's socket:// handler, the host on the accepted connection."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        host, port = server.getsockname()
        ecu_side = open_transport(f"socket://{host}:{port}")
        conn, _ = server.accept()
    booted = boot(EcuParams(), None)
    ecu = Ecu(booted.table.firmware)
    service = ServicePort(ecu_side, ecu, booted, seed=3)
    inputs = EcuInputs()

    def tick() -> None:
        service.poll(inputs)
        ecu.tick(inputs)
        time.sleep(0.001)

    client = ServiceClient(_SocketEnd(conn), timeout_s=5.0, retries=0, idle=tick)
    assert client.identify()["param_crc"] == _expected_set_crc(EcuParams())
    assert client.set("egt_kp", 0.02)["value"] == pytest.approx(0.02, abs=2**-24)
    conn.close()
    for _ in range(3):
        tick()  # the host is gone: the ECU side keeps polling without raising
    ecu_side.close()


def test_a_repeated_request_is_answered_again_not_run_again(rig):
    seed_request = encode_frame(pack(Message(Kind.REQUEST, 500, Service.UNLOCK_SEED)))
    answers = []
    for _ in range(2):  # the client's retry: the same sequence number and service
        rig.transport.write(seed_request)
        rig.tick()
        answers += [unpack(p) for p in rig.client.decoder.feed(rig.transport.read(4096))]
    assert [m.seq for m in answers] == [500, 500]
    assert answers[0].body == answers[1].body  # the same seed: the request ran once
    assert rig.client.counters()["repeats"] == 1
    assert rig.client.request(Service.UNLOCK_SEED) != answers[0].body  # a new request runs


def test_an_error_quoting_a_long_request_still_fits_a_frame(rig):
    name = "\u00e9" * 120  # 240 bytes of UTF-8: the answer quotes it
    with pytest.raises(ServiceRequestError, match="UNKNOWN_PARAM: unknown parameter '\u00e9\u00e9"):
        rig.client.request(Service.PARAM_READ, {"name": name})
    assert rig.client.identify()["protocol"] == 1  # and the port goes on


def test_a_full_fault_log_page_of_extreme_values_fits_a_frame(rig):
    big = 2**31 - 1
    for code in range(10, 16):
        rig.port.fault_log.record(big, code, (-big,) * len(fault_log.SNAPSHOT_FIELDS))
    for entry in rig.port.fault_log.entries:
        entry.count = entry.last_tick = big
    entries = rig.client.faults()
    assert len(entries) == 6 and entries[-1]["snapshot"]["pump_ma"] == -big
    assert entries[-1]["count"] == big


def test_a_burst_of_repeats_is_counted_and_keeps_the_older_entries():
    log = fault_log.FaultLog()
    snap = (0,) * len(fault_log.SNAPSHOT_FIELDS)
    log.record(1, 7, snap)  # FLAMEOUT, the event worth keeping
    for k in range(500):  # a burst of alternating repeats, 20 ms apart
        log.record(10 + 2 * k, fault_log.START_ABORT + 6, snap)
        log.record(11 + 2 * k, 11, snap)
    assert [e.code for e in log.entries] == [7, fault_log.START_ABORT + 6, 11]
    assert [e.count for e in log.entries] == [1, 500, 500]
    assert log.entries[1].tick == 10 and log.entries[1].last_tick == 1008
    assert log.total == 1001


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.binary(max_size=3000))
def test_line_noise_never_raises_out_of_a_tick(noise):
    rig = LoopRig(EcuParams())
    rig.transport.write(noise)
    rig.ticks(8)  # up to 512 bytes a tick
    rig.transport.read(1 << 16)  # whatever the port answered to frames the noise held
    assert rig.client.identify()["protocol"] == 1


def test_a_start_abort_is_logged_once_with_its_reason_and_state():
    log = fault_log.FaultLog()
    snap = tuple(range(len(fault_log.SNAPSHOT_FIELDS)))
    log.update(10, 0, snap, abort_reason=0)
    log.update(11, 0, snap, abort_reason=1)  # IGNITION_TIMEOUT
    log.update(12, 0, snap, abort_reason=1)  # the same abort, still reported: not again
    log.update(13, 0, snap, abort_reason=0)  # a new start
    log.update(14, 0, snap, abort_reason=4)  # HOT_START
    codes = [(e.tick, fault_log.code_name(e.code)) for e in log.entries]
    assert codes == [(11, "START_ABORT_IGNITION_TIMEOUT"), (14, "START_ABORT_HOT_START")]
    assert log.entries[0].snapshot[fault_log.SNAPSHOT_FIELDS.index("seq_state")] == 7


def test_the_sequencer_thresholds_are_written_and_checked_as_a_set(rig):
    c = rig.client
    c.unlock()
    with pytest.raises(ServiceRequestError, match=r"INVALID: start_cutoff_pct: .*start_idle_pct"):
        c.set("start_cutoff_pct", 55.0)  # over the hand-over speed
    with pytest.raises(ServiceRequestError, match=r"INVALID: start_egt_target_k: .*limit"):
        c.set("start_egt_target_k", 1300.0)  # over the hot-start limit
    c.set("start_accel_pct_s", 3.0)
    c.set("relight_max", 0)
    expected = compile_params(EcuParams(start_accel_pct_s=3.0, relight_max=0))
    assert rig.ecu.p.seq_accel_q24 == expected.seq_accel_q24
    assert rig.ecu.p.seq_relight_max == 0
