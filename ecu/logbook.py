"""The engine's logbook: lifetime counts kept by the firmware, stored in flash with the
parameter set (ecu.service.storage) and read over XCP (the ``logbook`` region).

Its words are the ``log_*`` fields at the end of the state (ecu.state.EcuState), updated by the
tick's logbook stage after the health stage (:func:`logbook_step`, C ``stage_logbook``):

- ``log_runs``: engine runs, an entry into RUN that is not a relight's (a run lasts from its
  entry into RUN until the ECU leaves ARMED and RUN: a relight stays in the same run);
- ``log_run_time_s``: whole seconds spent in RUN (``log_run_frac_ticks`` the ticks of the
  second under way, 0 .. rate_hz - 1, stored too);
- ``log_starts``: arms that began a start (OFF -> ARMED);
- ``log_aborts``: starts (and relights) that ended in ARMED with a sequencer abort reason, one
  counter per reason (index reason - 1: ecu.start_sequencer.REASONS[1:], STOPPED included);
- ``log_last_max_egt_dk`` (0.1 K) and ``log_last_max_speed_cpct`` (0.01 %N): the highest EGT
  and speed of the last run (of the run under way, while one is);
- ``log_last_shutdown``: why the last start or run ended (:data:`SHUTDOWN_NAMES`);
- ``log_in_run``: 1 while a run is under way (volatile: not stored).

Counters saturate at INT32_MAX and never wrap. At power-up the logbook is zero until the node
loads the stored words (:func:`load_words`); a stored set without a logbook leaves it at zero.
"""

from __future__ import annotations

from typing import Any

from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.fixedpoint import INT32_MAX
from ecu.params import LOG_ABORTS
from ecu.state import EcuState

N_ABORTS = LOG_ABORTS  # one counter per abort reason (NONE has none)
if len(Q.REASONS) - 1 != N_ABORTS:
    raise RuntimeError("ecu.params.LOG_ABORTS must count the start abort reasons")

# why the last start or run ended (log_last_shutdown)
SD_NONE = 0
SD_OPERATOR_STOP = 1  # a stop request or the arm released
SD_DEMAND_LOST = 2  # demand frames lost for the shutdown time
SD_FLAMEOUT = 3  # a flameout in RUN with no relight left
SD_START_ABORT = 4  # the start sequencer aborted (the reason is counted in log_aborts)
SD_FAULT = 5  # a trip to the latched FAULT
SHUTDOWN_NAMES = ("NONE", "OPERATOR_STOP", "DEMAND_LOST", "FLAMEOUT", "START_ABORT", "FAULT")

# the stored words, in order (log_aborts expanded): what flash and the XCP region hold
STORED = (
    "log_runs", "log_run_time_s", "log_run_frac_ticks", "log_starts", "log_aborts",
    "log_last_max_egt_dk", "log_last_max_speed_cpct", "log_last_shutdown",
)  # fmt: skip
ABORT_NAMES = tuple(name.lower() for name in Q.REASONS[1:])
STORE_KEY = "_logbook"  # its key in the stored set (ecu.service.param_table.ParamTable.image)


def _inc(x: int) -> int:
    return x + 1 if x < INT32_MAX else INT32_MAX


def _shutdown_reason(new_mode: int, start_abort: int, demand_lost: int, trip_shutdown: int) -> int:
    if new_mode == M.FAULT:
        return SD_FAULT
    if start_abort:
        return SD_START_ABORT
    if demand_lost:
        return SD_DEMAND_LOST
    if trip_shutdown:
        return SD_FLAMEOUT
    return SD_OPERATOR_STOP


def logbook_step(
    s: EcuState,
    mode: int,
    new_mode: int,
    start_abort: int,
    demand_lost: int,
    trip_shutdown: int,
    n_cpct: int,
    rate_hz: int,
) -> None:
    """One tick of the logbook on the state ``s`` (ecu.state.EcuState): the mode's transition
    from ``mode`` to ``new_mode``, this tick's start abort and shutdown trips, the speed used."""
    if new_mode == M.ARMED and mode == M.OFF:
        s.log_starts = _inc(s.log_starts)
    if new_mode == M.RUN and not s.log_in_run:
        s.log_in_run = 1
        s.log_runs = _inc(s.log_runs)
        s.log_last_max_egt_dk = 0
        s.log_last_max_speed_cpct = 0
    if s.log_in_run:
        if s.egt_dk > s.log_last_max_egt_dk:
            s.log_last_max_egt_dk = s.egt_dk
        if n_cpct > s.log_last_max_speed_cpct:
            s.log_last_max_speed_cpct = n_cpct
    if new_mode == M.RUN:
        if s.log_run_frac_ticks >= rate_hz - 1:  # a second is full
            s.log_run_frac_ticks = 0
            s.log_run_time_s = _inc(s.log_run_time_s)
        else:
            s.log_run_frac_ticks += 1
    if (mode == M.ARMED or mode == M.RUN) and new_mode != M.ARMED and new_mode != M.RUN:
        s.log_in_run = 0
        if mode == M.ARMED and Q.NO_ABORT < s.seq_reason <= N_ABORTS:
            k = s.seq_reason - 1
            s.log_aborts[k] = _inc(s.log_aborts[k])
        s.log_last_shutdown = _shutdown_reason(new_mode, start_abort, demand_lost, trip_shutdown)


def stored_words(s: Any) -> list[int]:
    """The logbook's stored words (:data:`STORED` order, log_aborts expanded) of a state (the
    Python firmware's or the C core's: the same field names)."""
    words: list[int] = []
    for name in STORED:
        if name == "log_aborts":
            words.extend(int(s.log_aborts[k]) for k in range(N_ABORTS))
        else:
            words.append(int(getattr(s, name)))
    return words


def stored_dict(s: Any) -> dict[str, int]:
    """The logbook as a save stores it: {word name: value} (:func:`word_names`)."""
    return dict(zip(word_names(), stored_words(s), strict=True))


def word_names() -> tuple[str, ...]:
    """The stored words' names, log_aborts expanded by reason."""
    names: list[str] = []
    for name in STORED:
        if name == "log_aborts":
            names.extend(f"log_aborts_{a}" for a in ABORT_NAMES)
        else:
            names.append(name)
    return tuple(names)


def load_words(s: Any, stored: object) -> list[str]:
    """Load a stored logbook ({word name: value}) into the state ``s``; returns the problems
    (a word missing or not an int32 count: left at its value). Called at power-up only."""
    problems: list[str] = []
    for name in word_names():
        value = stored.get(name) if isinstance(stored, dict) else None
        if not isinstance(value, int) or not 0 <= value <= INT32_MAX:
            problems.append(f"logbook {name}: stored value {value!r} not loaded")
        elif name.startswith("log_aborts_"):
            s.log_aborts[ABORT_NAMES.index(name[len("log_aborts_") :])] = value
        else:
            setattr(s, name, value)
    return problems
