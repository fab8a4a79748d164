"""Runs sharing a bus: each node hears its own run's frames, with DBC IDs, and counts the rest."""

import random
import threading

import can
import pytest

from protocol.bus import open_bus, unique_udp_spec
from protocol.node import run_lockstep
from protocol.run_bus import SIMRUN_ID, RunBus, simrun_payload

SENSORS, ACTUATOR = 0x100, 0x110


def _buses(kind: str, tags: list[int]) -> list[RunBus]:
    virtual = f"virtual:run-bus-{random.randrange(1 << 30)}"
    spec = virtual if kind == "virtual" else unique_udp_spec()
    return [RunBus(open_bus(spec), tag) for tag in tags]


def _drain(bus: RunBus) -> list[tuple[int, bytes]]:
    frames = []
    while (got := bus.recv_frame(0.2)) is not None:
        frames.append(got if type(got) is tuple else (got.arbitration_id, bytes(got.data)))
    return frames


@pytest.mark.parametrize("kind", ["virtual", "udp"])
def test_each_run_hears_its_own_frames_with_dbc_ids(kind):
    primary, listener_0, other, listener_1 = _buses(kind, [0, 0, 1, 1])
    try:
        primary.send_frame(SENSORS, bytes(range(8)))
        other.send_frame(SENSORS, bytes(range(8, 16)))
        other.send(can.Message(arbitration_id=ACTUATOR, data=b"\x01\x02", is_extended_id=False))
        other.send_frame(SIMRUN_ID, simrun_payload(0xC0FFEE, 0))
        primary.send_frame(SIMRUN_ID, simrun_payload(0xBEEF, 0))
        assert _drain(listener_0) == [(SENSORS, bytes(range(8)))]
        assert _drain(listener_1) == [(SENSORS, bytes(range(8, 16))), (ACTUATOR, b"\x01\x02")]
        assert listener_0.stats() == {"run_tag": 0, "foreign_frames": 3, "foreign_runs": 1}
        assert listener_1.stats() == {"run_tag": 1, "foreign_frames": 2, "foreign_runs": 1}
    finally:
        for bus in (primary, listener_0, other, listener_1):
            bus.shutdown()


def test_the_primary_run_sends_what_a_plain_bus_sends():
    spec = unique_udp_spec()
    with RunBus(open_bus(spec), 0) as run, open_bus(spec) as plain, open_bus(spec) as tap:
        run.send_frame(SENSORS, bytes(8))
        tagged = tap.recv(1.0)
        plain.send_frame(SENSORS, bytes(8))
        untagged = tap.recv(1.0)
    assert tagged is not None and untagged is not None
    assert (tagged.arbitration_id, tagged.is_extended_id) == (SENSORS, False)
    assert tagged.equals(untagged, timestamp_delta=None, check_channel=False)


def test_a_later_run_goes_on_extended_ids():
    spec = unique_udp_spec()
    with RunBus(open_bus(spec), 5) as run, open_bus(spec) as tap:
        run.send_frame(SENSORS, bytes(8))
        msg = tap.recv(1.0)
    assert msg is not None and msg.is_extended_id and msg.arbitration_id == 5 << 11 | SENSORS


def test_runs_after_one_another_on_one_tag_count_as_two():
    (listener, first, second) = _buses("virtual", [0, 2, 2])
    try:
        first.send_frame(SIMRUN_ID, simrun_payload(1, 0))
        second.send_frame(SIMRUN_ID, simrun_payload(2, 0))
        second.send_frame(SENSORS, bytes(8))
        assert _drain(listener) == []
        assert listener.foreign_runs == 2 and listener.foreign_frames == 3
    finally:
        for bus in (listener, first, second):
            bus.shutdown()


def test_a_node_with_filters_still_counts_other_runs_frames_of_its_ids():
    listener, other = _buses("udp", [0, 1])
    try:
        listener.set_filters([{"can_id": ACTUATOR, "can_mask": 0x1FFFFFFF}])
        other.send_frame(ACTUATOR, bytes(8))
        other.send_frame(SENSORS, bytes(8))  # not of the node's IDs: dropped by the bus
        assert _drain(listener) == []
        assert listener.foreign_frames == 1
    finally:
        listener.shutdown()
        other.shutdown()


def test_frames_of_no_run_are_left_to_the_driver_or_counted_as_foreign():
    spec = f"virtual:run-bus-{random.randrange(1 << 30)}"
    with (
        open_bus(spec) as raw,
        RunBus(open_bus(spec), 0) as primary,
        RunBus(open_bus(spec), 1) as other,
    ):
        raw.send(can.Message(arbitration_id=0x100, is_extended_id=True, data=bytes(8)))
        raw.send(can.Message(is_error_frame=True))
        heard = [primary.recv_frame(0.2), primary.recv_frame(0.2)]
        assert heard[0].is_extended_id and heard[1].is_error_frame  # the driver counts them
        assert other.recv_frame(0.2).is_error_frame and other.recv_frame(0.2) is None
        assert (primary.foreign_frames, other.foreign_frames) == (0, 1)


def test_a_bad_tag_is_refused_and_the_bus_closed():
    bus = open_bus(unique_udp_spec())
    with pytest.raises(ValueError, match="tag 256"):
        RunBus(bus, 256)
    assert bus.socket.fileno() == -1


class _Echo:
    """Answers each sensor frame with an actuator frame, for ``ticks`` ticks."""

    frame_ids = (SENSORS,)

    def __init__(self, ticks: int) -> None:
        self.ticks = ticks
        self.heard: list[bytes] = []
        self.finished = False

    def start(self, send) -> None:
        pass

    def on_frame(self, frame_id, data, send) -> None:
        self.heard.append(bytes(data))
        send(ACTUATOR, data)
        self.finished = len(self.heard) == self.ticks

    def on_timeout(self, send) -> None:
        pass


def test_two_runs_in_lockstep_on_one_bus_keep_apart():
    """Two runs' drivers on one bus: each node hears its run's frames; a tap of each run hears
    its node's answers and counts the other run's frames."""
    buses = _buses("udp", [0, 0, 1, 1])
    nodes = {0: _Echo(20), 1: _Echo(20)}
    threads = [
        threading.Thread(target=run_lockstep, args=(nodes[0], buses[0]), daemon=True),
        threading.Thread(target=run_lockstep, args=(nodes[1], buses[2]), daemon=True),
    ]
    try:
        for thread in threads:
            thread.start()
        for k in range(20):
            for tag, peer in ((0, buses[1]), (1, buses[3])):
                peer.send_frame(SENSORS, bytes([tag, k, 0, 0, 0, 0, 0, 0]))
        for thread in threads:
            thread.join(5.0)
        for tag, peer in ((0, buses[1]), (1, buses[3])):
            sent = [bytes([tag, k, 0, 0, 0, 0, 0, 0]) for k in range(20)]
            assert nodes[tag].heard == sent
            assert _drain(peer) == [(ACTUATOR, data) for data in sent]
            assert peer.stats() == {"run_tag": tag, "foreign_frames": 40, "foreign_runs": 1}
    finally:
        for bus in buses:
            bus.shutdown()
