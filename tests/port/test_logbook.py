"""The engine's logbook in the firmware: the Python tick and the C core count the same, every
tick, over scripted starts (aborts of every reason, relights, a run) and a run that ends in a
FAULT; the counts are those read off the trace (the modes and abort reasons tick by tick)."""

from __future__ import annotations

from functools import cache

import pytest

from ecu import golden
from ecu import logbook as L
from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.firmware import Ecu, EcuInputs
from ecu.fixedpoint import INT32_MAX
from ecu.port.core import CEcu
from sil.run import golden as sources

OUT = {name: len(golden.INPUT_FIELDS) + k for k, name in enumerate(golden.OUTPUT_FIELDS)}
IN = {name: k for k, name in enumerate(golden.INPUT_FIELDS)}


@cache
def _vector(name: str) -> golden.Golden:
    if name == "start-stop":
        return sources.record_start_stop(3000)
    return sources.record_modes(2400)


def _inputs(g: golden.Golden, k: int, i: EcuInputs) -> EcuInputs:
    row = g.rows[k * golden.ROW_WORDS : k * golden.ROW_WORDS + len(golden.INPUT_FIELDS)]
    for name, value in zip(golden.INPUT_FIELDS, row, strict=True):
        setattr(i, name, value)
    return i


def _column(g: golden.Golden, name: str) -> list[int]:
    return list(g.rows[OUT[name] :: golden.ROW_WORDS])


def _expected(g: golden.Golden) -> dict[str, int]:
    """The logbook read off the trace: a run is a stretch of ARMED / RUN ticks with RUN in it
    (a relight stays in its run), a start a tick from OFF into ARMED, an abort a stretch that
    ends in ARMED with a sequencer reason (the reason shown on the tick that ends it)."""
    mode, reason = _column(g, "mode"), _column(g, "seq_reason")
    speed = _column(g, "n_cpct")
    egt = list(g.rows[IN["egt_dk"] :: golden.ROW_WORDS])
    out = dict.fromkeys(L.word_names(), 0)
    prev = M.OFF
    in_run = False
    run_ticks = 0
    for k, m in enumerate(mode):
        if m == M.ARMED and prev == M.OFF:
            out["log_starts"] += 1
        if m == M.RUN and not in_run:
            in_run = True
            out["log_runs"] += 1
            out["log_last_max_egt_dk"] = out["log_last_max_speed_cpct"] = 0
        if in_run:
            out["log_last_max_egt_dk"] = max(out["log_last_max_egt_dk"], egt[k])
            out["log_last_max_speed_cpct"] = max(out["log_last_max_speed_cpct"], speed[k])
        run_ticks += m == M.RUN
        if prev in (M.ARMED, M.RUN) and m not in (M.ARMED, M.RUN):
            in_run = False
            if prev == M.ARMED and reason[k]:
                out[f"log_aborts_{Q.REASONS[reason[k]].lower()}"] += 1
        prev = m
    out["log_run_time_s"], out["log_run_frac_ticks"] = divmod(run_ticks, g.params.rate_hz)
    return out


def _run_both(g: golden.Golden, py: Ecu, c: CEcu) -> None:
    i = EcuInputs()
    for k in range(g.ticks):
        _inputs(g, k, i)
        py.tick(i)
        c.tick(i)
        assert L.stored_words(py.s) == L.stored_words(c.s), f"tick {k}"
        assert py.s.log_in_run == c.s.log_in_run, f"tick {k}"


@pytest.mark.parametrize("name", ["start-stop", "modes"])
def test_python_and_c_keep_the_same_logbook_every_tick(name):
    g = _vector(name)
    py, c = Ecu(g.params), CEcu(g.params)
    _run_both(g, py, c)
    found = dict(zip(L.word_names(), L.stored_words(py.s), strict=True))
    expected = _expected(g)
    del found["log_last_shutdown"]
    del expected["log_last_shutdown"]
    assert found == expected


def test_the_scripted_starts_count_every_abort_reason_and_the_runs():
    py = Ecu(_vector("start-stop").params)
    _run_both(_vector("start-stop"), py, CEcu(py.p))
    found = dict(zip(L.word_names(), L.stored_words(py.s), strict=True))
    assert all(found[f"log_aborts_{name}"] >= 1 for name in L.ABORT_NAMES)
    assert found["log_runs"] == 2  # the runs from rest; their relights stay in them
    assert found["log_starts"] >= 8
    # the last run: two flameouts, one relight, then SHUTDOWN for the flameout
    assert found["log_last_shutdown"] == L.SD_FLAMEOUT
    assert 4000 <= found["log_last_max_speed_cpct"] <= 5000  # idle 40 %N, demand 45 %N


@pytest.mark.parametrize(
    ("name", "named"),
    [
        ("start-stop", {L.SD_START_ABORT, L.SD_OPERATOR_STOP, L.SD_FLAMEOUT}),
        ("modes", {L.SD_FLAMEOUT, L.SD_FAULT}),
    ],
)
def test_the_last_shutdown_names_why_each_run_ended(name, named):
    """Every reason the scripts end a start or run with is named, in Python and C alike; the
    pump stall of ``modes`` ends in FAULT, named last."""
    g = _vector(name)
    py, c = Ecu(g.params), CEcu(g.params)
    i = EcuInputs()
    seen = set()
    for k in range(g.ticks):
        _inputs(g, k, i)
        py.tick(i)
        c.tick(i)
        assert py.s.log_last_shutdown == c.s.log_last_shutdown
        seen.add(py.s.log_last_shutdown)
    assert seen - {L.SD_NONE} == named
    if name == "modes":
        assert py.out.mode == M.FAULT and py.s.log_last_shutdown == L.SD_FAULT


def test_counters_saturate_in_both():
    g = _vector("start-stop")
    for e in (Ecu(g.params), CEcu(g.params)):
        e.s.log_runs = e.s.log_starts = e.s.log_run_time_s = INT32_MAX
        for k in range(L.N_ABORTS):
            e.s.log_aborts[k] = INT32_MAX
        i = EcuInputs()
        for k in range(g.ticks):
            e.tick(_inputs(g, k, i))
        assert e.s.log_runs == e.s.log_starts == e.s.log_run_time_s == INT32_MAX
        assert list(e.s.log_aborts) == [INT32_MAX] * L.N_ABORTS


def test_the_logbook_stage_is_on_the_checked_firmware_path():
    """The no-allocation and integer-only checks run over the logbook's module."""
    from tests.ecu.test_allocation_and_integers import FIRMWARE_MODULES

    assert "logbook" in FIRMWARE_MODULES
