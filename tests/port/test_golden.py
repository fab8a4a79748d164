"""Golden vectors: the host build of the C core replays the Python firmware's every tick."""

import subprocess
from array import array
from collections import Counter

import pytest

from ecu import faults as F
from ecu import golden
from ecu.params import CTRL_MRAC, CTRL_OPEN_LOOP, CTRL_PI, CTRL_PID
from ecu.port import build
from sil.run import golden as sources

NAMES = list(sources.SOURCES)
OUT = {name: len(golden.INPUT_FIELDS) + k for k, name in enumerate(golden.OUTPUT_FIELDS)}
IN = {name: k for k, name in enumerate(golden.INPUT_FIELDS)}


def _column(g: golden.Golden, index: int) -> list[int]:
    return list(g.rows[index :: golden.ROW_WORDS])


def _replay(path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(build.host_replayer()), str(path)], capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize("name", NAMES)
def test_host_build_matches_every_tick(vectors, name):
    path, g = vectors[name]
    done = _replay(path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.strip() == f"OK {g.ticks} ticks"
    assert g.ticks >= 1000


def test_no_undefined_behaviour_on_any_vector(vectors):
    """UBSan (signed overflow, shifts, ...) and ASan stop the replay at the first finding."""
    replayer = build.host_replayer(sanitize=True)
    for name, (path, g) in vectors.items():
        done = subprocess.run([str(replayer), str(path)], capture_output=True, text=True)
        assert done.returncode == 0 and done.stderr == "", f"{name}: {done.stdout}{done.stderr}"
        assert done.stdout.strip() == f"OK {g.ticks} ticks"


def test_vectors_cover_controllers_modes_limiters_and_faults(vectors):
    gs = [g for _, g in vectors.values()]
    assert {g.params.controller for g in gs} == {CTRL_MRAC, CTRL_PID, CTRL_OPEN_LOOP, CTRL_PI}
    modes = Counter(m for g in gs for m in _column(g, OUT["mode"]))
    assert set(modes) == {0, 1, 2, 3, 4}  # OFF ARMED RUN SHUTDOWN FAULT
    owners = {o for g in gs for o in _column(g, OUT["owner"])}
    assert owners >= {0, 1, 2, 4}  # speed, EGT limit, acceleration limit, deceleration floor
    word = 0
    for g in gs:
        for w in _column(g, OUT["fault_word"]):
            word |= w
    for bit in (
        F.EGT_OPEN, F.SPEED_STUCK, F.SPEED_SUBSTITUTED, F.EGT_OVERTEMP, F.OVERSPEED, F.PUMP_STALL,
        F.PUMP_HEALTH, F.DEMAND_LOST, F.SENSOR_FRAME_LOST, F.ANALOG_FRAME_LOST,
        F.LIMITER_ACTIVE, F.PUMP_SATURATED,
    ):  # fmt: skip
        assert word & bit, F.NAMES[bit]
    statuses = {s for g in gs for s in _column(g, IN["sensor_status"])}
    assert statuses >= {0, 3, 4}  # OK, WRONGCRC, NONEWDATA
    assert max(_column(vectors["mrac-reproducing"][1], OUT["sat_events"])) > 0  # saturation counted


def test_start_stop_vector_covers_the_sequencer(vectors):
    """The scripted start and stop passes every sequencer state and abort reason, relights
    after flameouts in RUN and drives the starter and the igniter; `modes` runs without it."""
    from ecu import modes as M
    from ecu import start_sequencer as Q

    g = vectors["start-stop"][1]
    assert g.params.start_on == 1 and vectors["modes"][1].params.start_on == 0
    assert set(_column(g, OUT["seq_state"])) == set(range(len(Q.NAMES)))
    assert set(_column(g, OUT["seq_reason"])) == set(range(len(Q.REASONS)))
    mode = _column(g, OUT["mode"])
    relights = sum(1 for a, b in zip(mode, mode[1:], strict=False) if (a, b) == (M.RUN, M.ARMED))
    assert relights >= 2
    starter = set(_column(g, OUT["starter_cpct"]))
    assert {0, g.params.seq_start_cpct, g.params.seq_cool_cpct, 10000} <= starter
    assert set(_column(g, OUT["igniter"])) == {0, 1}
    assert g.ticks >= 1000 and mode[-1] == M.OFF


def test_replayer_reports_the_first_differing_integer(vectors, tmp_path):
    path, g = vectors["modes"]
    params, rows = golden.read_rows(path)
    head = 5 + len(params)
    data = array("i", path.read_bytes())
    tick = 1234
    data[head + tick * golden.ROW_WORDS + OUT["duty_cpct"]] += 1
    bad = tmp_path / "bad.gv"
    bad.write_bytes(data.tobytes())
    done = _replay(bad)
    assert done.returncode == 1
    word = golden.OUTPUT_FIELDS.index("duty_cpct")
    assert done.stdout.startswith(f"MISMATCH tick {tick} output word {word}:")
    data[head + tick * golden.ROW_WORDS + OUT["duty_cpct"]] -= 1
    data[head + (tick + 1) * golden.ROW_WORDS - 1] ^= 1  # the state digest
    bad.write_bytes(data.tobytes())
    done = _replay(bad)
    assert done.returncode == 1 and done.stdout.startswith(f"MISMATCH tick {tick} state digest")


def test_bad_files_are_refused_with_their_name(vectors, tmp_path):
    path, _ = vectors["modes"]
    short = tmp_path / "short.gv"
    short.write_bytes(path.read_bytes()[:-6])
    done = _replay(short)
    assert done.returncode == 2 and done.stdout.startswith(f"{short}: truncated at tick")
    junk = tmp_path / "junk.gv"
    junk.write_bytes(b"not a vector file")
    done = _replay(junk)
    assert done.returncode == 2 and f"{junk}: not a golden-vector file" in done.stdout
    with pytest.raises(golden.GoldenError, match="junk.gv"):
        golden.read_rows(junk)
    with pytest.raises(golden.GoldenError, match="short.gv"):
        golden.read_rows(short)


def test_digest_covers_the_whole_state(vectors):
    """The digest changes with any state word (else the replay could miss a state difference)."""
    from ecu.firmware import Ecu

    ecu = Ecu()
    base = golden.state_digest(ecu.s)
    changed = set()
    for name in ecu.s.FIELDS:
        value = getattr(ecu.s, name)
        if isinstance(value, array):
            value[len(value) - 1] += 1
            changed.add(golden.state_digest(ecu.s))
            value[len(value) - 1] -= 1
        else:
            setattr(ecu.s, name, value + 1)
            changed.add(golden.state_digest(ecu.s))
            setattr(ecu.s, name, value)
    assert base not in changed and len(changed) == len(ecu.s.FIELDS)
