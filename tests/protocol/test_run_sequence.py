"""Another sender's frames on a run's bus are told from the run's own (protocol.run_sequence):
fed a run's frames as each node hears them, with another run's frames of the same IDs mixed in
anywhere, a node keeps exactly the run's, in their order, and counts the rest."""

from __future__ import annotations

import random
from pathlib import Path

import can
import pytest

from protocol.codec import Codec
from protocol.run_sequence import COMMAND, ECU, PLANT, RunSequence, sent_by

SCENARIO = """
duration_s = {duration}
seed = {seed}
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
params = {{ rate_window_s = 0.05 }}
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 93, 88]
step_s = 4
[[fault]]
time_s = 1.0
target = "PUMP_EFFECTIVENESS"
value = 0.9
"""
SENSORS, ACTUATOR, TRUTH_A = 0x100, 0x110, 0x300
Frame = tuple[int, bytes]


def _log(tmp_path: Path, name: str, duration: float, seed: int) -> list[Frame]:
    from sil import scenario
    from sil.runner import RunOptions, run

    path = tmp_path / f"{name}.toml"
    path.write_text(SCENARIO.format(duration=duration, seed=seed))
    out = tmp_path / name
    summary = run(RunOptions(scenario.load(str(path)), out, mode="inproc", plots=False,
                             progress=False))  # fmt: skip
    assert summary["status"] == "completed"
    return [(m.arbitration_id, bytes(m.data)) for m in can.CanutilsLogReader(str(out / "can.log"))]


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> tuple[list[Frame], list[Frame]]:
    """A 3 s run's frames, and another run's (another seed) from its tick 2000 on: a replay of
    a log that the run does not overtake."""
    tmp = tmp_path_factory.mktemp("logs")
    run = _log(tmp, "run", 3.0, 1)
    other = _log(tmp, "other", 30.0, 2)
    start = next(
        i
        for i, (f, d) in enumerate(other)
        if f == SENSORS and d[2:4] == (2000).to_bytes(2, "little")
    )
    return run, other[start:]


def _hear(sequence: RunSequence, frames: list[Frame], role: str, sends: set[int]) -> list[Frame]:
    """What a node of ``role`` is handed of ``frames`` (the bus order): the frames it sends
    itself (``sends``, from the run's log) go through ``sent``, the rest through ``heard``."""
    out: list[Frame] = []
    for frame_id, data in frames:
        if (frame_id, data) in sends:
            sequence.sent(frame_id)
        else:
            out += sequence.heard((frame_id, data), frame_id, data)
    return out


def _mix(run: list[Frame], other: list[Frame], rng: random.Random) -> list[Frame]:
    """``other``'s frames put into ``run`` at random places, each keeping its order."""
    mixed = list(run)
    for frame in other:
        mixed.insert(rng.randrange(len(mixed) + 1), frame)
    return mixed


@pytest.mark.parametrize("role", [COMMAND, ECU, PLANT])
def test_a_node_keeps_exactly_the_runs_frames_with_another_senders_mixed_in(logs, role):
    run, other = logs
    codec = Codec()
    own = sent_by(codec, role)
    sends = {f for f in run if f[0] in own}
    expected = [f for f in run if f[0] not in own]
    clean = RunSequence(codec, 100.0, own)
    assert _hear(clean, run, role, sends) == expected
    assert clean.foreign_frames == 0
    for seed in range(3):
        sequence = RunSequence(codec, 100.0, own)
        foreign = other[: len(run) // 10]  # (a replay at 1x beside a run at 40x: 1/40)
        heard = _hear(sequence, _mix(run, foreign, random.Random(seed)), role, sends)
        assert heard == expected, seed
        assert sequence.foreign_frames == len(foreign)  # every one of them, whatever its ID
        assert set(sequence.foreign) == {f for f, _ in foreign}


def test_a_second_frame_of_a_message_in_one_turn_is_told_apart_by_its_values(logs):
    run, other = logs
    codec = Codec()
    truth = [i for i, f in enumerate(run) if f[0] == TRUTH_A]
    at = truth[5]  # a run's PlantTruthA, and another sender's with the same alive counter
    twin = next(d for f, d in other if f == TRUTH_A and d[1] & 0x0F == run[at][1][1] & 0x0F)
    for mixed in (run[:at] + [(TRUTH_A, twin)] + run[at:], run[: at + 1] + [(TRUTH_A, twin)]
                  + run[at + 1 :]):  # fmt: skip
        own = sent_by(codec, COMMAND)
        sequence = RunSequence(codec, 100.0, own)
        heard = _hear(sequence, mixed, COMMAND, {f for f in run if f[0] in own})
        assert heard == [f for f in run if f[0] not in own]
        assert sequence.ties == 1 and sequence.foreign == {TRUTH_A: 1}


def test_own_ids_unknown_ids_and_the_xcp_transport():
    codec = Codec()
    ecu = RunSequence(codec, 100.0, sent_by(codec, ECU))
    assert ecu.heard("a", ACTUATOR, bytes(8)) == []  # the ECU hears an EcuActuator: not its own
    assert ecu.heard("b", 0x555, bytes(8)) == []  # no message of the run
    assert ecu.heard("c", 0x700, b"\xff\x00") == ["c"]  # an XCP master's command: passed on
    assert ecu.foreign == {ACTUATOR: 1, 0x555: 1}
    assert ecu.stats() == {
        "other_sender_frames": 2,
        "other_sender_ids": {"0x110": 1, "0x555": 1},
    }
    loose = RunSequence(codec, 100.0, sent_by(codec, ECU), strict=False)  # real time, bus faults
    assert loose.heard("a", ACTUATOR, bytes(8)) == []
    assert loose.heard("b", 0x555, bytes(8)) == ["b"]  # left to the recorder's unknown_ids
    assert loose.heard("d", SENSORS, bytes(8)) == ["d"]  # no sequence checked
    held = RunSequence(codec, 100.0, sent_by(codec, COMMAND))
    analog = codec["PlantAnalog"]
    analog.pack_raw([0, 22000, 1000])
    assert held.heard("analog", analog.frame_id, analog.data) == []  # held to the turn's end
    assert held.relax() == ["analog"]  # the lockstep is over: handed on
    assert held.heard("x", SENSORS, bytes(8)) == ["x"]
