"""Start and stop sequencer: from 0 rpm to idle on the starter, igniter and pump, and from the
fuel cut to a cool engine, as small-turbine ECUs (JetCat, Xicoy, Hornet) sequence them.

Start (in mode ARMED), each step with a timeout and an abort reason:

    SPIN_UP    starter at start_duty, igniter heating; fuel off (the air purges the burner)
               -> IGNITION once purged and at the ignition speed   (else STARTER_FAILURE)
    IGNITION   pump voltage ramping from ign_v0 at ign_v_step per tick up to ign_v_max;
               light-off when the EGT rose light_rise_dk above a reference that follows it
               down at once and up at most light_track (a combustion's rise, not the hot
               metal's heat soaking into a slowing flow after a flameout)
               -> RAMP                                                (else IGNITION_TIMEOUT)
    RAMP       lit: the starter ramps to full; the pump voltage ramps up while the shaft
               accelerates slower than accel_q24 and the EGT is under the start target, holds
               while it accelerates faster, backs off over the EGT target (an integrating
               acceleration control with an EGT limit), never above the acceleration line;
               -> STABILISE at the cut-off speed
               (HOT_START over the start limit, FLAMEOUT if the EGT falls back, SLOW_ACCEL on
               the timeout)
    STABILISE  starter off, the same fuel ramp; -> RUN at the idle speed (SLOW_ACCEL, HOT_START)

Stop (in mode SHUTDOWN): SPOOL_DOWN with the fuel cut until the rotor is slow enough for the
starter's clutch; then, while the EGT is over cool_egt_dk, COOL_DOWN blows air through with the
starter at cool_duty (until cool, or cool_timeout); then DONE, which the mode logic takes as
cooled once it held soak_ticks: the hot section's metal soaks its heat back into the still gas as
the rotor stops, and an EGT back over cool_egt_dk + cool_rearm_dk cools again.

A relight (relight_max attempts after a flameout in RUN) goes straight to IGNITION with the
starter assisting. All voltages Q7.24 V, temperatures 0.1 K (dk), speeds rpm, duties 0.01 %.
"""

from __future__ import annotations

from typing import ClassVar

from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import INT32_MAX, clamp
from ecu.state import EcuState

OFF = 0
SPIN_UP = 1
IGNITION = 2
RAMP = 3
STABILISE = 4
RUN = 5
SPOOL_DOWN = 6
COOL_DOWN = 7
DONE = 8
NAMES = (
    "OFF", "SPIN_UP", "IGNITION", "RAMP", "STABILISE", "RUN", "SPOOL_DOWN", "COOL_DOWN", "DONE",
)  # fmt: skip

# abort reasons
NO_ABORT = 0
IGNITION_TIMEOUT = 1  # no light-off within ign_timeout
SLOW_ACCEL = 2  # lit, but not at cut-off / idle within their timeouts (a hung start)
STARTER_FAILURE = 3  # the starter did not bring the rotor to the ignition speed
HOT_START = 4  # EGT over the start limit
FLAMEOUT = 5  # the flame went out during the start (the EGT fell back)
STOPPED = 6  # stop request or arm released during the start
REASONS: tuple[str, ...] = (
    "NONE",
    "IGNITION_TIMEOUT",
    "SLOW_ACCEL",
    "STARTER_FAILURE",
    "HOT_START",
    "FLAMEOUT",
    "STOPPED",
)

DUTY_FULL_CPCT = 10000


class SeqOut:
    """The sequencer's commands for this tick (one preallocated record)."""

    FIELDS: ClassVar[tuple[str, ...]] = ("v_q24", "starter_cpct", "igniter")
    __slots__ = FIELDS
    v_q24: int
    starter_cpct: int
    igniter: int

    def __init__(self) -> None:
        self.v_q24 = 0
        self.starter_cpct = 0
        self.igniter = 0


def _enter(s: EcuState, state: int) -> None:
    s.seq_state = state
    s.seq_timer = 0


def start_begin(s: EcuState, relight: int) -> None:
    """Begin a start (SPIN_UP) or, for a relight, the ignition with the engine still turning."""
    s.seq_reason = NO_ABORT
    s.seq_v_q24 = 0
    if relight:
        s.seq_egt_ref_q8 = s.egt_dk << 8
        _enter(s, IGNITION)
    else:
        _enter(s, SPIN_UP)


def _fuel_ramp(s: EcuState, p: FirmwareParams, egt_dk: int, rate_q24: int, v_cap_q24: int) -> None:
    """The lit engine's fuel: down by ramp_v_step over the start's EGT target on the day
    (ecu.inlet), else up by it
    while the shaft accelerates slower than accel_q24 (held while faster), within
    [ign_v0, min(v_cap, v_max)]."""
    step = 0
    if egt_dk >= s.seq_target_dk:
        step = -p.seq_ramp_v_step_q24
    elif rate_q24 < p.seq_accel_q24:
        step = p.seq_ramp_v_step_q24
    s.seq_v_q24 = clamp(s.seq_v_q24 + step, p.seq_ign_v0_q24, min(v_cap_q24, p.v_max_q24))


def start_step(
    s: EcuState,
    p: FirmwareParams,
    n_rpm: int,
    egt_dk: int,
    rate_q24: int,
    v_cap_q24: int,
    o: SeqOut,
) -> int:
    """One tick of the start in ARMED at speed n_rpm, EGT egt_dk and speed rate rate_q24 (%N/s,
    Q7.24); commands into o. Returns an abort reason (NO_ABORT while starting); s.seq_state is
    RUN once the engine is at idle (hand over to the speed control)."""
    s.seq_timer = s.seq_timer + 1 if s.seq_timer < INT32_MAX else INT32_MAX
    state = s.seq_state
    t = s.seq_timer
    abort = NO_ABORT
    o.igniter = 0
    o.starter_cpct = 0
    if state == SPIN_UP:
        o.starter_cpct = p.seq_start_cpct
        o.igniter = 1
        if t >= p.seq_purge_ticks and n_rpm >= p.seq_ign_rpm:
            s.seq_egt_ref_q8 = egt_dk << 8
            s.seq_v_q24 = p.seq_ign_v0_q24
            _enter(s, IGNITION)
        elif t >= p.seq_spinup_ticks:
            abort = STARTER_FAILURE
    elif state == IGNITION:
        o.starter_cpct = p.seq_start_cpct
        o.igniter = 1
        if s.seq_v_q24 < p.seq_ign_v0_q24:
            s.seq_v_q24 = p.seq_ign_v0_q24
        else:
            s.seq_v_q24 = min(s.seq_v_q24 + p.seq_ign_v_step_q24, p.seq_ign_v_max_q24)
        s.seq_egt_ref_q8 = min(egt_dk << 8, s.seq_egt_ref_q8 + p.seq_light_track_q8)
        if egt_dk >= (s.seq_egt_ref_q8 >> 8) + p.seq_light_rise_dk:
            _enter(s, RAMP)
        elif t >= p.seq_ign_ticks:
            abort = IGNITION_TIMEOUT
    elif state == RAMP:
        o.starter_cpct = min(p.seq_start_cpct + t * p.seq_starter_step_cpct, DUTY_FULL_CPCT)
        o.igniter = 1 if t < p.seq_igniter_hold_ticks else 0
        _fuel_ramp(s, p, egt_dk, rate_q24, v_cap_q24)
        if n_rpm >= p.seq_cutoff_rpm:
            _enter(s, STABILISE)
        elif t >= p.seq_ramp_ticks:
            abort = SLOW_ACCEL
        elif t >= p.seq_igniter_hold_ticks and egt_dk < (s.seq_egt_ref_q8 >> 8) + (
            p.seq_light_rise_dk >> 1
        ):
            abort = FLAMEOUT
    elif state == STABILISE:
        _fuel_ramp(s, p, egt_dk, rate_q24, v_cap_q24)
        if n_rpm >= p.seq_idle_rpm:
            _enter(s, RUN)
        elif t >= p.seq_stabilise_ticks or n_rpm < p.seq_ign_rpm:
            abort = SLOW_ACCEL
    if abort == NO_ABORT and egt_dk > p.seq_hot_dk:
        abort = HOT_START
    if abort != NO_ABORT:
        s.seq_reason = abort
        o.starter_cpct = 0
        o.igniter = 0
        s.seq_v_q24 = 0
    o.v_q24 = s.seq_v_q24
    return abort


def cooled(s: EcuState, p: FirmwareParams) -> int:
    """The stop is over: DONE, and held for soak_ticks without the EGT soaking back."""
    return 1 if (s.seq_state == DONE and s.seq_timer >= p.seq_soak_ticks) else 0


def stop_step(s: EcuState, p: FirmwareParams, n_rpm: int, egt_dk: int, o: SeqOut) -> None:
    """One tick of the stop in SHUTDOWN (fuel cut): spool down, cool down with the starter once
    the rotor is slow enough for its clutch, DONE when cool (back to COOL_DOWN if the metal's
    heat soaks back into the gas by more than cool_rearm_dk within the soak time); a cool-down
    that times out ends in DONE at once, soaked."""
    s.seq_timer = s.seq_timer + 1 if s.seq_timer < INT32_MAX else INT32_MAX
    o.v_q24 = 0
    o.igniter = 0
    o.starter_cpct = 0
    s.seq_v_q24 = 0
    state = s.seq_state
    if state != SPOOL_DOWN and state != COOL_DOWN and state != DONE:
        _enter(s, SPOOL_DOWN)
        state = SPOOL_DOWN
    hot = egt_dk > p.seq_cool_egt_dk
    if state == SPOOL_DOWN:
        if n_rpm <= p.seq_cool_rpm:
            _enter(s, COOL_DOWN if hot else DONE)
    elif state == COOL_DOWN:
        if not hot:
            _enter(s, DONE)
        elif s.seq_timer >= p.seq_cool_ticks:  # given up (an EGT that stays high): no re-arm
            _enter(s, DONE)
            s.seq_timer = p.seq_soak_ticks
    elif (
        s.seq_timer < p.seq_soak_ticks
        and egt_dk > p.seq_cool_egt_dk + p.seq_cool_rearm_dk
        and n_rpm <= p.seq_cool_rpm
    ):
        _enter(s, COOL_DOWN)  # the metal's heat soaked back: cool again
    if s.seq_state == COOL_DOWN:
        o.starter_cpct = p.seq_cool_cpct
