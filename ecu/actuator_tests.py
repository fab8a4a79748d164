"""Bench test functions: the igniter, the starter or the pump run alone for a time the ECU
counts, as ground-support units offer them with the engine at rest (the glow plug check, a
starter spin, a pump prime).

The request is an input of the tick (``EcuInputs.test_request``: 1 glow plug, 2 starter spin,
3 pump prime, 0 end; ``test_level``: the starter's duty in 0.01 % or the pump's voltage in mV,
ignored for the glow plug; ``test_ms``: the duration). The firmware acts on it in OFF only: a
new request (a value other than the last tick's) starts a test when it is within its limits
(:func:`request_ok`); leaving OFF, an arm or a stop request, or the request going to 0 ends it
at once, and it ends by itself when its time is up. A held request is not started again: the
bench (ecu.service.bench_control, the C slave) drops it once the test is over.

Limits: the glow plug at most 10 s, the starter 15 s at a duty up to the start's
(``seq_start_cpct``), the pump 5 s at a voltage up to the ignition's highest
(``seq_ign_v_max_q24``). During a test the outputs go out in the normal frames: the igniter and
the starter duty in EcuStarter, the pump's enable, voltage and duty in EcuActuator.
"""

from __future__ import annotations

from ecu.firmware_params import FirmwareParams
from ecu.params import RATE_MAX_HZ
from ecu.pump_driver import volts_q24_to_mv
from ecu.state import EcuState

NONE = 0
GLOW = 1  # the igniter (glow plug) on
STARTER = 2  # the starter at test_level, 0.01 % duty
PRIME = 3  # the pump enabled at test_level, mV
NAMES = ("NONE", "GLOW", "STARTER", "PRIME")
MAX_MS = (0, 10_000, 15_000, 5_000)  # the longest test of each kind, ms
MAX_TICKS = MAX_MS[STARTER] * RATE_MAX_HZ // 1000  # the longest test in ticks, at any rate


def level_max(p: FirmwareParams, test: int) -> int:
    """The highest level of a test: the start's starter duty, the ignition's pump voltage."""
    if test == STARTER:
        return p.seq_start_cpct
    if test == PRIME:
        return volts_q24_to_mv(p.seq_ign_v_max_q24)
    return 0


def request_ok(p: FirmwareParams, test: int, level: int, ms: int) -> int:
    """1 when a test of kind ``test`` at ``level`` for ``ms`` is within its limits."""
    if test < GLOW or test > PRIME or ms < 1 or ms > MAX_MS[test]:
        return 0
    if test != GLOW and (level < 1 or level > level_max(p, test)):
        return 0
    return 1


def actuator_test_step(
    s: EcuState, p: FirmwareParams, request: int, level: int, ms: int, allowed: int
) -> int:
    """One tick of the test functions: start, hold or end the test (``allowed``: the ECU is in
    OFF with no arm or stop request). Returns the test that drives the outputs this tick (NONE:
    none); s.test_active is the one still running after it."""
    fresh = 1 if request != s.test_request_last else 0
    s.test_request_last = request
    if not allowed or request == NONE:  # none runs
        s.test_active = NONE
        s.test_ticks_left = 0
        s.test_time_left_ms = 0
        return NONE
    if fresh and request_ok(p, request, level, ms):
        s.test_active = request
        s.test_level_held = level
        s.test_ticks_left = (ms * p.rate_hz + 999) // 1000
    test = s.test_active
    if test < GLOW or test > PRIME or s.test_ticks_left < 1 or s.test_ticks_left > MAX_TICKS:
        test = NONE  # none running (or a state no start leaves: ended)
        s.test_active = NONE
        s.test_ticks_left = 0
    else:
        s.test_ticks_left -= 1
        if s.test_ticks_left == 0:
            s.test_active = NONE  # its time is up: this tick is its last
    s.test_time_left_ms = s.test_ticks_left * 1000 // p.rate_hz
    return test
