"""Who belongs to a run: its nodes say their senders in the handshake files and hear only each
other from tick 0 on, so a second ECU that joins the run's loopback bus during the set-up never
enters the record; where frames name no sender, a run that heard another sender is not reported
as clean."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from protocol.bus import open_bus, unique_udp_spec
from protocol.codec import Codec
from protocol.dbc import xcp_frame_ids
from protocol.run_bus import RunBus
from protocol.run_sequence import RunSequence, sent_by
from sil import scenario as scenarios
from sil.run.membership import give_start, say_ready, sender_in, senders_in, wait_to_start
from sil.run.run_record import scenario_text
from sil.run.runner import RunOptions, run
from sil.run.summary import TOUCHED, _other_senders

STATUS = 0x200  # EcuStatus


def _drain(bus: RunBus) -> list[tuple[int, bytes]]:
    frames = []
    while (got := bus.recv_frame(0.2)) is not None:
        frames.append(got if type(got) is tuple else (got.arbitration_id, bytes(got.data)))
    return frames


def test_a_node_that_admitted_the_runs_senders_drops_any_other_naming_it():
    spec = unique_udp_spec()
    listener, member, stranger = (RunBus(open_bus(spec)) for _ in range(3))
    try:
        assert listener.admit([member.sender, listener.sender])
        member.send_frame(STATUS, bytes(8))
        stranger.send_frame(STATUS, bytes(range(8)))
        stranger.send_frame(0x210, bytes(range(1, 9)))
        assert _drain(listener) == [(STATUS, bytes(8))]
        stats = listener.stats()
        assert stats["other_sender_frames"] == 2 and stats["foreign_frames"] == 2
        assert stats["other_sender_ids"] == {"0x200": 1, "0x210": 1}
        assert stats["other_sender_first"][0] == (
            f"0x200 0001020304050607: sent by {stranger.sender}, not a sender of the run"
        )
    finally:
        for bus in (listener, member, stranger):
            bus.shutdown()


def test_an_xcp_master_is_heard_whoever_it_is():
    """A master (`sil console`, `sil gsu`, pyXCP) on the run's bus is not a sender of the run;
    the XCP transport's frames are heard from any sender, with a sequence or without."""
    codec = Codec()
    master_id, ecu_id = xcp_frame_ids()
    spec = unique_udp_spec()
    sequence = RunSequence(codec, 100.0, sent_by(codec, "ECU"))
    ecu, plain = RunBus(open_bus(spec), 0, sequence), RunBus(open_bus(spec))
    master = RunBus(open_bus(spec))
    try:
        for bus in (ecu, plain):
            bus.admit([])
        master.send_frame(master_id, b"\xff\x00")
        master.send_frame(ecu_id - 0x10, bytes(8))  # (no message of the run's senders' own)
        assert _drain(ecu) == [(master_id, b"\xff\x00")]
        assert _drain(plain) == [(master_id, b"\xff\x00")]
        assert ecu.stats()["other_sender_frames"] == plain.stats()["other_sender_frames"] == 1
    finally:
        for bus in (ecu, plain, master):
            bus.shutdown()


def test_a_frame_of_another_sender_counts_in_the_runs_sequence_at_its_tick():
    """However well it fits the run's sequence (EcuStatus due at tick 0, counter 0): dropped by
    its sender, counted where the sequence counts another sender's frames."""
    codec = Codec()
    spec = unique_udp_spec()
    sequence = RunSequence(codec, 100.0, sent_by(codec, "Command"))
    listener = RunBus(open_bus(spec), 0, sequence)
    member, stranger = RunBus(open_bus(spec)), RunBus(open_bus(spec))
    try:
        listener.admit([member.sender])
        status = codec["EcuStatus"]
        status.pack([0.0] * len(status.signal_names))  # (alive counter 0: the run's first)
        stranger.send_frame(STATUS, bytes(status.data))
        assert _drain(listener) == []
        assert sequence.foreign == {STATUS: 1}
        assert sequence.first[0].endswith(f"at tick 0: sent by {stranger.sender}, not a sender "
                                          "of the run")  # fmt: skip
    finally:
        for bus in (listener, member, stranger):
            bus.shutdown()


def test_the_handshake_names_each_nodes_sender_and_the_start_file_admits_them(tmp_path):
    spec = unique_udp_spec()
    node, command, stranger = (RunBus(open_bus(spec)) for _ in range(3))
    try:
        say_ready(tmp_path / ".ecu-ready", node)
        assert sender_in(tmp_path / ".ecu-ready") == node.sender
        assert sender_in(tmp_path / ".plant-ready") is None  # (not there)
        start = tmp_path / ".start"
        assert not wait_to_start(start, node, lambda: True)  # a stop before the go
        give_start(start, {"command": command.sender, "ecu": node.sender})
        assert senders_in(start) == {"command": command.sender, "ecu": node.sender}
        assert sorted(p.name for p in tmp_path.iterdir()) == [".ecu-ready", ".start"]
        assert wait_to_start(start, node, lambda: False)
        command.send_frame(0x080, bytes(8))
        stranger.send_frame(0x080, bytes(range(8)))
        assert _drain(node) == [(0x080, bytes(8))]
        assert node.stats()["other_sender_frames"] == 1
    finally:
        for bus in (node, command, stranger):
            bus.shutdown()


def test_a_node_waiting_to_start_holds_what_comes_and_hears_it_by_the_start_files_senders(
    tmp_path,
):
    """Another run floods the bus while the node waits for its start (more frames than its
    queue holds): nothing of its own run is lost, and the flood is dropped by its sender."""
    spec = unique_udp_spec()
    node, command, flood = (RunBus(open_bus(spec)) for _ in range(3))
    start = tmp_path / ".start"
    waiting = threading.Thread(target=wait_to_start, args=(start, node, lambda: False))
    waiting.start()
    try:
        for _ in range(40):  # 2000 frames, in bursts a sender might send
            for _ in range(50):
                flood.send_frame(0x100, bytes(8))
            time.sleep(0.002)
        command.send_frame(0x080, bytes(range(8)))
        give_start(start, {"command": command.sender})
        waiting.join(10)
        assert _drain(node) == [(0x080, bytes(range(8)))]
        assert node.stats()["other_sender_frames"] == 2000
    finally:
        waiting.join(10)
        for bus in (node, command, flood):
            bus.shutdown()


def test_a_start_file_naming_no_one_leaves_every_sender_heard(tmp_path):
    spec = unique_udp_spec()
    node, other = RunBus(open_bus(spec)), RunBus(open_bus(spec))
    try:
        give_start(tmp_path / ".start", {})
        assert wait_to_start(tmp_path / ".start", node, lambda: False)
        other.send_frame(0x080, bytes(8))
        assert _drain(node) == [(0x080, bytes(8))]
        assert node.stats() == {"run_tag": 0, "foreign_frames": 0, "foreign_runs": 0}
    finally:
        node.shutdown()
        other.shutdown()


def _summary(**extra: object) -> dict:
    return {
        "status": "completed",
        "abort_reason": None,
        "missed_ticks": 0,
        "other_sender_frames": 4,
        "other_sender_ids": {"0x110": 2, "0x200": 2},
        "other_sender_first": ["0x200 3d20 at tick 0: a second frame of its message in the turn"],
        **extra,
    }


def test_another_senders_frames_where_frames_name_no_sender_leave_the_run_touched(capsys):
    summary = _summary()
    _other_senders(summary)
    assert summary["status"] == TOUCHED != "completed"
    reason = summary["abort_reason"]
    assert reason.startswith("foreign frames on the bus: 4 from another sender (IDs 0x110, 0x200")
    assert "first dropped by run: 0x200 3d20 at tick 0" in reason
    assert "the run's record may hold some of them" in reason
    assert capsys.readouterr().err == ""  # (said by `sil run` with the status)


def test_another_senders_frames_dropped_by_sender_leave_a_completed_run_warned(capsys):
    summary = _summary(run_senders={"command": "udp-1", "plant": "udp-2", "ecu": "udp-3"})
    _other_senders(summary)
    assert summary["status"] == "completed" and summary["abort_reason"] is None
    assert "they were left out of the run" in summary["warnings"][0]
    assert "sil run: warning: foreign frames on the bus: 4" in capsys.readouterr().err


def _short(tmp_path: Path, seconds: float) -> Path:
    s = replace(scenarios.load("thesis-5.4-staircase"), duration_s=seconds, seed=5)
    path = tmp_path / "short.toml"
    path.write_text(scenario_text(s, 5))
    return path


@pytest.mark.slow
def test_a_second_ecu_on_the_bus_at_set_up_never_enters_a_lockstep_runs_record(
    tmp_path, udp_spec, sil, sil_process
):
    """`sil ecu --bus SAME` listening while a lockstep run sets up answers every PlantSensors
    of the run, tick 0's first; the run's record is the lone run's byte for byte, or the run
    is not reported completed."""
    path = _short(tmp_path, 2.0)
    alone = tmp_path / "alone"
    s = scenarios.load(str(path))
    assert run(RunOptions(s, alone, mode="inproc", plots=False, progress=False))["status"] == (
        "completed"
    )
    spec = udp_spec()
    ready = tmp_path / "second-ready"
    second = sil_process("ecu", "--bus", spec, "--ready-file", str(ready),
                         stdout=subprocess.DEVNULL)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not ready.exists():  # on the bus before the run's set-up begins
            assert second.poll() is None and time.monotonic() < deadline, second.stderr.read()
            time.sleep(0.05)
        out = tmp_path / "shared"
        result = sil("run", str(path), "--bus", spec, "--out", str(out), "--no-plots", timeout=300)
    finally:
        second.terminate()
        second.wait(10)
    summary = json.loads((out / "summary.json").read_text())
    assert "Traceback" not in result.stderr
    assert summary["other_sender_frames"] > 0  # it answered the run, and was dropped
    first = summary["other_sender_first"][0]
    assert first.startswith("0x") and "not a sender of the run" in first, first
    same = (out / "can.log").read_bytes() == (alone / "can.log").read_bytes()
    if summary["status"] == "completed":
        assert same and result.returncode == 0
        assert summary["run_senders"].keys() == {"command", "plant", "ecu"}
        assert f"first dropped by run: {first}" in result.stderr
    else:
        assert result.returncode == 1
        assert f"sil run: {summary['status']}: foreign frames on the bus" in result.stderr
