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
    from sil.run.runner import RunOptions, run

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
    # a replay playing while the node waits for the run to start: a second of it before tick 0
    early = RunSequence(codec, 100.0, own)
    flood = [f for f in other[:1500] if f[0] not in own]
    assert _hear(early, flood + run, role, sends) == expected
    assert early.foreign_frames == len(flood) and early.resyncs == 0


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
        "other_sender_first": [  # what was dropped first, where and why
            "0x110 0000000000000000 at tick 0: an ID this node sends",
            "0x555 0000000000000000 at tick 0: no message of the run",
        ],
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


def _missing(heard: list[Frame], expected: list[Frame]) -> list[int]:
    """Where in ``expected`` the frames ``heard`` leaves out (``heard`` must be ``expected`` less
    some frames, in order)."""
    out, j = [], 0
    for i, frame in enumerate(expected):
        if j < len(heard) and heard[j] == frame:
            j += 1
        else:
            out.append(i)
    assert j == len(heard), "a frame heard that is not the run's, or out of order"
    return out


@pytest.mark.parametrize("role", [COMMAND, ECU, PLANT])
def test_a_frame_of_the_run_lost_or_late_costs_that_turn_only(logs, role):
    """The bus loses one of the run's frames, or delivers one after its turn's last frame: the
    node drops at most the frames of that tick, and from the next tick on keeps every frame of
    the run again (rule 5), its sequence taken up from the frames that follow."""
    run, _ = logs
    codec = Codec()
    own = sent_by(codec, role)
    sends = {f for f in run if f[0] in own}
    expected = [f for f in run if f[0] not in own]
    ends = [i for i, f in enumerate(run) if f[0] in (SENSORS, ACTUATOR)]
    rng = random.Random(7)
    heard_ids = [i for i, f in enumerate(run) if f[0] not in own]
    # (a node in lockstep does not send its turn's frames without its peer's last one: the
    # peer's last frame lost is the command node's case, which hears both)
    may_lose = [i for i in heard_ids if role == COMMAND or run[i][0] not in (SENSORS, ACTUATOR)]
    for at in rng.sample(may_lose[20:-40], 25):
        turn_end = next(e for e in ends if e >= at)
        late = run[at][0] not in (SENSORS, ACTUATOR, 0x080, 0x310) and rng.random() < 0.5
        if late:  # after its turn's last frame
            frames = run[:at] + run[at + 1 : turn_end + 1] + [run[at]] + run[turn_end + 1 :]
        else:  # lost
            frames = run[:at] + run[at + 1 :]
        sequence = RunSequence(codec, 100.0, own)
        heard = _hear(sequence, frames, role, sends)
        missing = [heard_ids[i] for i in _missing(heard, expected)]
        assert at in missing, (at, run[at])
        window = (ends[max(0, ends.index(turn_end) - 2)], ends[ends.index(turn_end) + 2])
        assert all(window[0] <= i <= window[1] for i in missing), (at, run[at], missing)
        assert sequence.foreign_frames == (len(missing) if late else len(missing) - 1)
        assert sequence.resyncs >= 1


def test_a_replayed_fault_injection_is_never_taken_out_of_sequence(logs):
    """A FaultInject carries no tick: one with another counter than the run's next is dropped,
    whatever else (rule 5 does not apply to it)."""
    codec = Codec()
    plant = RunSequence(codec, 100.0, sent_by(codec, PLANT))
    fault = codec["FaultInject"]
    fault.pack([1, 0, 0.8])
    data = bytearray(fault.data)
    data[1] = (data[1] & 0xF0) | 5  # the run's next counter is 0
    assert plant.heard("f", fault.frame_id, data) == []
    assert plant.first == ["0x310 " + bytes(data).hex() + " at tick 0: alive counter 5, the "
                           "run's next is 0"]  # fmt: skip


def test_the_command_node_puts_a_turn_that_came_early_back_in_the_runs_order(logs):
    """What the command node was seen to hear on a loaded machine: the ECU's answer to tick k
    (up to its EcuActuator) before the plant's PlantSensors(k), which the ECU had heard already
    (the loopback hands a datagram to its listeners one by one). Rule 6: every frame kept, and
    handed on in the run's order, as if none had come early."""
    run, _ = logs
    codec = Codec()
    own = sent_by(codec, COMMAND)
    sends = {f for f in run if f[0] in own}
    expected = [f for f in run if f[0] not in own]
    sensors = [i for i, f in enumerate(run) if f[0] == SENSORS]
    rng = random.Random(3)
    for at in rng.sample(sensors[5:-5], 40):
        answer = next(i for i in range(at, len(run)) if run[i][0] == ACTUATOR)
        upto = rng.randrange(at + 1, answer + 1)  # some of the ECU's frames, or all of them
        frames = run[:at] + run[at + 1 : upto + 1] + [run[at]] + run[upto + 1 :]
        sequence = RunSequence(codec, 100.0, own)
        assert _hear(sequence, frames, COMMAND, sends) == expected, at
        assert sequence.foreign_frames == 0 and sequence.resyncs == 0
