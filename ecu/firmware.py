"""The ECU firmware: one state object, one ``tick(inputs) -> outputs`` (inputs, outputs, state
and parameters around one step, as Embedded Coder and PX4 lay it out).

Inputs and outputs are raw integers in the CAN contract's units. The tick allocates nothing that
survives it: the output record and the record of what the stages hand each other
(:class:`TickVars`) are reused, state lives in preallocated slots and int32 arrays, and the
firmware path uses integers only. One tick runs these stages, in this order, with the same names
as the C port's ``ecu_tick`` (``ecu/port/ecu_core.c``):

1. sensors: frame freshness (E2E status per frame kind), the speed checks (range, rate, stuck)
   and the EGT open-circuit check, speed substituted by the fast-model observer once failed;
   supply and pump current; demand hold, idle and shutdown on demand loss;
2. history: speed history, central-difference rate and the filtered rate (ecu.rate_filter);
3. trips: overspeed, flameout, EGT over its maximum, pump current, sensor frames lost;
4. start sequencer: in ARMED, the start's starter, igniter and pump, or an abort;
5. mode: the mode transition (ecu.modes) and what it starts (a start, a relight, RUN's entry);
6. control law (RUN): estimator (eq. 4.7/4.31), MRAC (eq. 5.4/5.16), PID, scheduled PI or open
   loop, reference model (eq. 5.18-5.19);
7. limit selection (RUN): min/max selection with the limit loops and fuel schedules, voltage
   limits and slew, integrator tracking, observer (eq. 3.5);
8. pump driver: PWM duty from the measured supply; the stop's cool-down outside RUN;
9. actuator tests: in OFF, a bench test function's igniter, starter or pump (ecu.actuator_tests);
10. health: pump health, fault word, saturation count and outputs;
11. logbook: runs, time in RUN, starts, aborts by reason, the last run's highest EGT and speed,
   the last shutdown's reason (ecu.logbook).
"""

from __future__ import annotations

from typing import ClassVar

from mypy_extensions import mypyc_attr

from ecu import actuator_tests as T
from ecu import faults as F
from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.estimator import estimator_step
from ecu.fast_model import observer_step
from ecu.firmware_params import FirmwareParams, compile_params
from ecu.fixedpoint import (
    INT32_MAX,
    clamp,
    counting_into,
    div_trunc,
    mul_q,
    new_sat_counter,
    sat32,
    sub_sat,
    take_sat_events,
)
from ecu.inlet import take_egt_at_rest
from ecu.limiters import (
    OWNER_SPEED,
    egt_lead_step,
    pump_from_start,
    reset_loops,
    schedule_v,
    select_voltage,
)
from ecu.logbook import logbook_step
from ecu.mrac import command_lag, mrac_control, mrac_gain_update, reference_model_step
from ecu.params import (
    CTRL_MRAC,
    CTRL_PI,
    CTRL_PID,
    EGT_ERROR_MAX_DK,
    LOG_ABORTS,
    RATE_BUF_LEN,
    EcuParams,
)
from ecu.pi import pi_control, pi_track
from ecu.pid import pid_control, pid_track
from ecu.pump_driver import pump_current_checks, pump_duty, volts_q24_to_mv
from ecu.rate_filter import rate_filter_start, rate_filter_step
from ecu.state import AP21, AP22, KF1, KF2, KR, KX1, KX2, LAM, N_THETA, PID_I, TH1, TH2, EcuState

# E2E receiver status per frame, as passed in by the node (AUTOSAR Profile 1/11 states)
E2E_OK = 0
E2E_REPEATED = 1
E2E_WRONGSEQUENCE = 2
E2E_WRONGCRC = 3
E2E_NONEWDATA = 4

RPM_PER_PCT = 1125  # 112,500 rpm = 100 %N
AGE_MAX = 1 << 30
# EcuState.inputs_seen: the sensors that gave a valid reading since power-up
SEEN_SPEED = 1
SEEN_EGT = 2
SEEN_ALL = SEEN_SPEED | SEEN_EGT
LATCHED = ~F.TRANSIENT  # the fault bits a tick starts from
TRIP_FAULT = F.OVERSPEED | F.EGT_OVERTEMP | F.PUMP_STALL | F.PUMP_DRY
SPEED_FAILS = F.SPEED_RANGE | F.SPEED_RATE | F.SPEED_STUCK  # a speed sensor failure (latched)


class EcuInputs:
    """One tick's inputs, raw integers as the CAN driver delivers them."""

    FIELDS: ClassVar[tuple[str, ...]] = (
        "tick",  # lockstep tick number of the sensor frame
        "speed_rpm",  # shaft speed, 1 rpm per count
        "egt_dk",  # EGT, 0.1 K per count
        "supply_mv",  # pump supply (battery) voltage, mV
        "pump_ma",  # pump current, mA
        "demand_cpct",  # speed demand, 0.01 %N_max per count
        "open_loop_mv",  # pump voltage demand for the open-loop controller, mV
        "arm",  # arm request bit
        "stop",  # stop request bit
        # per frame kind, what arrived since the last tick: E2E_OK (a fresh, valid frame: its
        # values above are used), REPEATED / WRONGSEQUENCE / WRONGCRC (one arrived but was
        # rejected) or NONEWDATA (none arrived). The firmware counts ages and timeouts itself.
        "sensor_status",  # sensor frame (speed, EGT): expected every tick
        "analog_status",  # analog frame (supply, pump current): every 50 ms
        "demand_status",  # demand frame (demand, open loop, arm, stop): every 50 ms
        # a bench test function (ecu.actuator_tests), acted on in OFF only: 1 glow plug,
        # 2 starter spin, 3 pump prime, 0 none / end; its level (starter duty 0.01 %, pump mV)
        # and duration (ms)
        "test_request",
        "test_level",
        "test_ms",
    )
    __slots__ = FIELDS
    tick: int
    speed_rpm: int
    egt_dk: int
    supply_mv: int
    pump_ma: int
    demand_cpct: int
    open_loop_mv: int
    arm: int
    stop: int
    sensor_status: int
    analog_status: int
    demand_status: int
    test_request: int
    test_level: int
    test_ms: int

    def __init__(self) -> None:
        for name in self.FIELDS:
            setattr(self, name, 0)


class EcuOutputs:
    """One tick's outputs (the same object is reused every tick)."""

    FIELDS: ClassVar[tuple[str, ...]] = (
        "tick",  # echo of the input tick (lockstep answer)
        "duty_cpct",  # pump PWM duty, 0.01 % per count (0..10000)
        "pump_mv",  # pump voltage aimed for, mV
        "pump_enable",  # pump driver enable bit
        "mode",  # OFF=0, ARMED=1, RUN=2, SHUTDOWN=3, FAULT=4
        "fault_word",  # 16-bit fault word (ecu.faults)
        "sat_events",  # saturation events since start-up (int32, saturating)
        "ap21_q24", "ap22_q24",  # A_p-hat row 2 (Q7.24)
        "lambda_q24",  # Lambda-hat (Q7.24)
        "theta21_q24", "theta22_q24",  # Theta_f-hat row 2 (Q7.24)
        "kx1_q24", "kx2_q24", "kr_q24", "kf1_q24", "kf2_q24",  # MRAC gains (Q7.24)
        "pump_health_pm",  # Lambda-hat / commissioning Lambda, 0.1 % per count
        "nref_cpct",  # reference-model speed, 0.01 %N per count
        "n_cpct",  # speed used by the control (measured or substituted), 0.01 %N per count
        "owner",  # which loop owns the pump command (ecu.limiters.OWNER_*)
        "starter_cpct",  # starter PWM duty, 0.01 % per count (0..10000)
        "igniter",  # igniter power bit
        "seq_state",  # start/stop sequencer state (ecu.start_sequencer)
        "seq_reason",  # the last start's abort reason (ecu.start_sequencer, 0: none)
        "inputs_valid",  # 1 once valid speed and EGT readings came since power-up
    )  # fmt: skip
    __slots__ = FIELDS
    tick: int
    duty_cpct: int
    pump_mv: int
    pump_enable: int
    mode: int
    fault_word: int
    sat_events: int
    ap21_q24: int
    ap22_q24: int
    lambda_q24: int
    theta21_q24: int
    theta22_q24: int
    kx1_q24: int
    kx2_q24: int
    kr_q24: int
    kf1_q24: int
    kf2_q24: int
    pump_health_pm: int
    nref_cpct: int
    n_cpct: int
    owner: int
    starter_cpct: int
    igniter: int
    seq_state: int
    seq_reason: int
    inputs_valid: int

    def __init__(self) -> None:
        for name in self.FIELDS:
            setattr(self, name, 0)


class TickVars:
    """What one tick's stages hand each other (preallocated: nothing survives the tick)."""

    FIELDS: ClassVar[tuple[str, ...]] = (
        "mode", "new_mode", "faults", "speed_ok", "egt_ok", "analog_fresh", "inputs_valid",
        "n_rpm", "n_q24", "dn", "rate", "ctrl_rate", "demand",
        "running", "trip_fault", "trip_shutdown", "relight", "start_abort",
        "u", "v", "pump_mv", "duty", "enable",
    )  # fmt: skip
    __slots__ = FIELDS
    mode: int
    new_mode: int
    faults: int
    speed_ok: int
    egt_ok: int
    analog_fresh: int
    inputs_valid: int
    n_rpm: int
    n_q24: int
    dn: int
    rate: int
    ctrl_rate: int
    demand: int
    running: int
    trip_fault: int
    trip_shutdown: int
    relight: int
    start_abort: int
    u: int
    v: int
    pump_mv: int
    duty: int
    enable: int

    def __init__(self) -> None:
        for name in self.FIELDS:
            setattr(self, name, 0)


def _q24_to_cpct(x_q24: int) -> int:
    """Q7.24 %N -> 0.01 %N per count, rounded."""
    return (x_q24 * 100 + (1 << 23)) >> 24


@mypyc_attr(allow_interpreted_subclasses=True)  # (a recording or test firmware)
class Ecu:
    """The firmware. ``Ecu(params)`` powers up in OFF; ``tick(inputs)`` runs one control step."""

    __slots__ = ("p", "s", "out", "seq", "t", "sat_pending")

    def __init__(self, params: EcuParams | FirmwareParams | None = None) -> None:
        if params is None:
            params = EcuParams()
        self.p = params if isinstance(params, FirmwareParams) else compile_params(params)
        self.s = EcuState()
        self.out = EcuOutputs()
        self.seq = Q.SeqOut()
        self.t = TickVars()
        self.sat_pending = new_sat_counter()  # this instance's saturation events (ecu_t's)
        self.reset()

    def reset(self) -> None:
        """Power-on initialisation (the only way out of a latched FAULT)."""
        s = self.s
        p = self.p
        for name in EcuState.FIELDS:
            v = getattr(s, name)
            if isinstance(v, int):
                setattr(s, name, 0)
        for k in range(N_THETA):
            s.theta_q24[k] = p.init_theta_q24[k]
            s.theta_ext[k] = 0
        for k in range(RATE_BUF_LEN):
            s.n_hist_rpm[k] = 0
            s.u_hist_q24[k] = 0
        for k in range(LOG_ABORTS):
            s.log_aborts[k] = 0  # the logbook: zero until the node loads the stored one
        s.supply_mv = p.supply_nominal_mv
        s.demand_q24 = p.idle_q24
        s.mode = M.OFF
        s.ncor_k_q24 = p.ncor_k_q24  # the operator's day (ecu.inlet)
        s.seq_target_dk = p.seq_day_target_dk
        take_sat_events(self.sat_pending)

    def _rate_q24(self, age: int) -> int:
        """Central difference of speed at the sample `age` ticks old, %N/s (Q7.24)."""
        s = self.s
        p = self.p
        m = p.rate_half_window
        hist = s.n_hist_rpm
        i_new = (s.hist_idx + RATE_BUF_LEN - age + m) % RATE_BUF_LEN
        i_old = (s.hist_idx + RATE_BUF_LEN - age - m) % RATE_BUF_LEN
        d_rpm = hist[i_new] - hist[i_old]
        return div_trunc((d_rpm * p.rpm_to_q24_k * p.rate_hz) >> 16, 2 * m)

    def _dn_q24(self, age: int) -> int:
        """Speed deviation from trim of the sample `age` ticks old (Q7.24 %N)."""
        s = self.s
        p = self.p
        rpm = s.n_hist_rpm[(s.hist_idx + RATE_BUF_LEN - age) % RATE_BUF_LEN]
        return sat32(((rpm * p.rpm_to_q24_k) >> 16) - p.trim_n_q24)

    def tick(self, i: EcuInputs) -> EcuOutputs:
        """One control step, in the stages the C port's ``ecu_tick`` runs in the same order."""
        s = self.s
        t = self.t
        outer = counting_into(self.sat_pending)  # this instance's saturations, as C's ecu_t
        try:
            s.ticks = s.ticks + 1 if s.ticks < INT32_MAX else INT32_MAX
            t.faults = s.faults & LATCHED
            t.mode = s.mode
            self._stage_sensors(i)
            self._stage_history()
            self._stage_trips()
            self._stage_start_sequencer()
            self._stage_mode()
            if t.new_mode == M.RUN:
                self._stage_control_law()
                self._stage_limit_selection()
            self._stage_pump_driver()
            self._stage_actuator_tests(i)
            self._stage_health(i)
            self._stage_logbook()
        finally:
            counting_into(outer)
        return self.out

    def _stage_sensors(self, i: EcuInputs) -> None:
        """The frames since the last tick: speed and EGT (checked; speed substituted by the
        observer once failed), supply and pump current, demand (held, then idle)."""
        s = self.s
        p = self.p
        t = self.t
        faults = t.faults
        if i.sensor_status == E2E_OK:
            rpm = i.speed_rpm
            egt_dk = i.egt_dk
            s.sensor_age = 0
            if s.speed_seen:
                faults |= F.speed_checks(s, p, rpm, s.speed_rpm, s.v_applied_q24)
            s.speed_rpm = rpm
            egt_lead_step(s, p, egt_dk)
            s.egt_dk = egt_dk
            faults |= F.egt_open_check(s, p, egt_dk)
            if s.inputs_seen != SEEN_ALL:
                s.inputs_seen |= F.valid_readings(p, rpm, egt_dk)
        else:
            s.sensor_age = s.sensor_age + 1 if s.sensor_age < AGE_MAX else AGE_MAX
            faults |= F.SENSOR_FRAME_LOST
        if faults & SPEED_FAILS:
            s.speed_failed = 1
        speed_ok = t.speed_ok = 1 if (s.speed_failed == 0 and s.sensor_age == 0) else 0
        t.inputs_valid = 1 if s.inputs_seen == SEEN_ALL else 0
        if speed_ok:
            t.n_rpm = s.speed_rpm
        elif not s.inputs_seen & SEEN_SPEED:
            t.n_rpm = 0  # no reading since power-up: nothing to substitute (not the trim speed)
        else:
            t.n_rpm = ((s.obs_n_q24 + p.trim_n_q24) * RPM_PER_PCT + (1 << 23)) >> 24
            if s.speed_failed:
                faults |= F.SPEED_SUBSTITUTED
        egt_ok = t.egt_ok = 1 if (faults & F.EGT_OPEN) == 0 else 0

        # analog frame: supply voltage and pump current
        analog_fresh = t.analog_fresh = 1 if i.analog_status == E2E_OK else 0
        if analog_fresh:
            s.analog_age = 0
            s.supply_mv = i.supply_mv
            s.pump_ma = i.pump_ma
        else:
            s.analog_age = s.analog_age + 1 if s.analog_age < AGE_MAX else AGE_MAX
            if s.analog_age > p.analog_loss_ticks:  # frames come every 50 ms: hold till then
                s.supply_mv = p.supply_nominal_mv
                faults |= F.ANALOG_FRAME_LOST

        # demand frame: hold 0.1 s, then idle, shut down after 2 s
        if i.demand_status == E2E_OK:
            s.demand_age = 0
            d = div_trunc(i.demand_cpct << 24, 100)
            s.demand_q24 = clamp(d, p.idle_q24, p.demand_max_q24)
            s.open_loop_q24 = div_trunc(i.open_loop_mv << 24, 1000)
            s.arm = 1 if i.arm else 0
            s.stop = 1 if i.stop else 0
        else:
            s.demand_age = s.demand_age + 1 if s.demand_age < AGE_MAX else AGE_MAX
        demand = s.demand_q24
        if s.demand_age > p.demand_hold_ticks:
            demand = p.idle_q24
            faults |= F.DEMAND_LOST
        if not egt_ok and demand > p.egt_fail_demand_q24:
            demand = p.egt_fail_demand_q24
        t.demand = demand
        t.faults = faults

    def _stage_history(self) -> None:
        """The speed history (raw rpm) and what it gives: speed deviation, the central-difference
        rate (the observer's while the sensor is out) and the filtered rate."""
        s = self.s
        p = self.p
        t = self.t
        speed_ok = t.speed_ok
        idx = s.hist_idx = (s.hist_idx + 1) % RATE_BUF_LEN
        s.n_hist_rpm[idx] = t.n_rpm
        u_hist = s.u_hist_q24
        u_hist[idx] = 0
        seen = s.speed_seen
        if seen < RATE_BUF_LEN:
            seen = s.speed_seen = seen + 1
        m = p.rate_half_window
        n_q24 = t.n_q24 = mul_q(t.n_rpm, p.rpm_to_q24_k, 16)
        dn = t.dn = sub_sat(n_q24, p.trim_n_q24)
        if not speed_ok:
            rate = s.obs_v_q24
        elif seen > 2 * m:
            rate = self._rate_q24(m)
        else:
            rate = 0
        t.rate = rate
        if seen == 1:
            rate_filter_start(s, dn)
        else:  # with the voltage applied over the last tick (0 outside RUN)
            u_last = u_hist[(idx + RATE_BUF_LEN - 1) % RATE_BUF_LEN]
            rate_filter_step(s, p, dn, u_last, speed_ok)
        # the control laws' and limit loops' rate: filtered while the sensor is valid
        t.ctrl_rate = s.rf_v_q24 if (p.rate_filter_on and speed_ok) else rate

    def _stage_trips(self) -> None:
        """Protection trips: overspeed, flameout, EGT over its maximum, pump current, sensor
        frames lost; which of them end in FAULT, which in SHUTDOWN (or a relight)."""
        s = self.s
        p = self.p
        t = self.t
        mode = t.mode
        n_rpm = t.n_rpm
        faults = t.faults
        egt_ok = t.egt_ok
        egt_dk = s.egt_dk
        in_run = mode == M.RUN
        running = 1 if (in_run or mode == M.ARMED) else 0
        # each persistence counter (F.persist); one at 0 with a good reading stays at 0
        bad = running and n_rpm > p.overspeed_rpm
        if bad or s.overspeed_cnt:
            s.overspeed_cnt = F.persist(s.overspeed_cnt, bad, p.overspeed_ticks)
        if s.overspeed_cnt >= p.overspeed_ticks:
            faults |= F.OVERSPEED
        bad = in_run and n_rpm < p.flameout_rpm
        if bad or s.flameout_cnt:
            s.flameout_cnt = F.persist(s.flameout_cnt, bad, p.flameout_ticks)
        bad = in_run and egt_ok and egt_dk < p.flameout_egt_dk
        if bad or s.flame_egt_cnt:
            s.flame_egt_cnt = F.persist(s.flame_egt_cnt, bad, p.flameout_egt_ticks)
        flameout = 0
        if s.flameout_cnt >= p.flameout_ticks or s.flame_egt_cnt >= p.flameout_egt_ticks:
            faults |= F.FLAMEOUT
            flameout = 1
        bad = running and egt_ok and egt_dk > p.egt_max_dk
        if bad or s.egt_over_cnt:
            s.egt_over_cnt = F.persist(s.egt_over_cnt, bad, p.egt_max_ticks)
        if s.egt_over_cnt >= p.egt_max_ticks:
            faults |= F.EGT_OVERTEMP
        if in_run and t.analog_fresh:
            faults |= pump_current_checks(s, p, s.pump_ma, s.v_applied_q24)
        t.trip_fault = 1 if (faults & TRIP_FAULT) else 0
        if running and s.sensor_age > p.sensor_loss_ticks:
            t.trip_fault = 1
        t.trip_shutdown = flameout
        if s.demand_age >= p.demand_shutdown_ticks:
            t.trip_shutdown = 1
        t.relight = 1 if (flameout and p.start_on and s.relights < p.seq_relight_max) else 0
        t.faults = faults

    def _stage_start_sequencer(self) -> None:
        """In ARMED, the start sequencer's step: this tick's starter, igniter and pump, or an
        abort; whether the engine runs (by the sequencer, else by the speed alone)."""
        s = self.s
        p = self.p
        t = self.t
        seq = self.seq
        seq.v_q24 = 0
        seq.starter_cpct = 0
        seq.igniter = 0
        t.start_abort = 0
        t.running = 1 if t.n_rpm >= p.run_entry_rpm else 0
        if t.mode == M.ARMED and p.start_on:
            v_cap = p.v_max_q24
            if p.fuel_schedules_on:  # the start's fuel stays under the acceleration line of
                # the weakest pump the schedules accept (no pump estimate yet in a start)
                v_cap = schedule_v(
                    s, p, p.accel_line_q24, t.n_q24, p.sched_lam_lo_q24, p.sched_lam_lo_q24
                )
            t.start_abort = Q.start_step(s, p, t.n_rpm, s.egt_dk, t.ctrl_rate, v_cap, seq)
            t.running = 1 if s.seq_state == Q.RUN else 0
            if (s.stop or not s.arm or t.trip_shutdown) and not t.start_abort:
                s.seq_reason = Q.STOPPED

    def _stage_mode(self) -> None:
        """The mode for this tick (ecu.modes) and what its transitions start: a start or a
        relight, the entry into RUN (bumpless at the entry voltage), the wait for a re-arm."""
        s = self.s
        p = self.p
        t = self.t
        mode = t.mode
        demand_fresh = 1 if s.demand_age <= p.demand_hold_ticks else 0
        if not s.arm:
            s.rearm_wait = 0
        new_mode = M.next_mode(
            mode,
            s.arm,
            s.stop,
            t.running,
            demand_fresh,
            t.trip_fault,
            1 if (t.trip_shutdown or t.start_abort) else 0,
            1 if t.n_rpm < p.shutdown_done_rpm else 0,
            1 if (t.start_abort or s.seq_state >= Q.IGNITION) else 0,
            t.relight,
            1 if (mode != M.SHUTDOWN or not p.start_on or Q.cooled(s, p)) else 0,  # SHUTDOWN's
            1 if (t.inputs_valid and demand_fresh and not s.rearm_wait) else 0,
        )
        if (mode == M.ARMED or mode == M.RUN) and new_mode != M.ARMED and new_mode != M.RUN:
            s.rearm_wait = s.arm  # a start is never retried by itself: the arm must drop first
        if new_mode == M.ARMED and mode != M.ARMED and p.start_on:  # a start or a relight
            if mode == M.RUN:
                s.relights += 1
                s.flameout_cnt = 0
                s.flame_egt_cnt = 0
            else:
                s.relights = 0
            Q.start_begin(s, 1 if mode == M.RUN else 0)
            if mode != M.RUN:
                take_egt_at_rest(s, p)
        if new_mode == M.OFF:
            s.seq_state = Q.OFF
        if new_mode == M.RUN and mode != M.RUN:
            self._enter_run(mode)
        s.mode = new_mode
        t.new_mode = new_mode

    def _enter_run(self, mode: int) -> None:
        """Entry into RUN: bumpless at the entry voltage (where the start left the pump), the
        loops, integrators and models started where the engine is."""
        s = self.s
        p = self.p
        t = self.t
        v_entry = p.entry_v_q24
        if mode == M.ARMED and p.start_on:
            v_entry = s.seq_v_q24  # where the start left the pump
            if p.fuel_schedules_on and p.pump_scaling_on:
                pump_from_start(s, p, t.n_q24, v_entry)
        s.seq_state = Q.RUN
        reset_loops(s, v_entry)
        s.hist_fill = 0
        s.theta_q24[PID_I] = sub_sat(v_entry, p.trim_v_q24)
        s.theta_ext[PID_I] = 0
        s.u_lag_q24 = s.theta_q24[PID_I]
        s.xm1_q24 = t.dn
        s.xm2_q24 = 0
        s.obs_n_q24 = t.dn
        s.obs_v_q24 = t.rate
        s.xh1_q24 = t.dn  # the identification model starts where the engine is
        s.xh2_q24 = t.rate

    def _stage_control_law(self) -> None:
        """In RUN: the estimator (eq. 4.7/4.31), the speed controller (MRAC eq. 5.4/5.16, PID,
        scheduled PI or open loop) and the reference model (eq. 5.18-5.19)."""
        s = self.s
        p = self.p
        t = self.t
        dn = t.dn
        if s.hist_fill < RATE_BUF_LEN:
            s.hist_fill += 1
        m = p.rate_half_window
        adapt = t.speed_ok
        # under the acceleration line the estimator learns the pump the line needs, from a
        # reading that answers the pump (not one that stays put while the pump moves: a
        # stuck sensor, before its fault trips, would teach a weak pump and raise the line)
        line_learns = s.line_owns and s.speed_stuck_cnt == 0
        if p.freeze_on and (s.v_saturated or (s.owner != OWNER_SPEED and not line_learns)):
            adapt = 0
        if p.adapt_band_q24 and (dn > p.adapt_band_q24 or dn < -p.adapt_band_q24):
            adapt = 0  # off the trim speed the fast model no longer holds
        if t.speed_ok and s.hist_fill > m + 1 and s.speed_seen > 2 * m + 1:
            # the interval m + 1 ticks back: dN and dN' at its ends (dN' at its end is the
            # history stage's rate, the sensor being valid) and the voltage held over it
            estimator_step(
                s,
                p,
                self._dn_q24(m + 1),
                self._rate_q24(m + 1),
                self._dn_q24(m),
                t.rate,
                s.u_hist_q24[(s.hist_idx + RATE_BUF_LEN - m - 1) % RATE_BUF_LEN],
                adapt,
            )
        demand = t.demand
        r = sub_sat(demand, p.trim_n_q24)
        if p.controller == CTRL_MRAC:
            t.u = command_lag(s, p, mrac_control(s, p, dn, t.ctrl_rate, r))
            mrac_gain_update(s, p)
        elif p.controller == CTRL_PID:
            t.u = pid_control(s, p, sat32(demand - t.n_q24), t.ctrl_rate)
        elif p.controller == CTRL_PI:
            t.u = pi_control(s, p, sat32(demand - t.n_q24), t.n_q24)
        else:
            t.u = sat32(s.open_loop_q24 - p.trim_v_q24)
        reference_model_step(s, p, r)

    def _stage_limit_selection(self) -> None:
        """In RUN: the EGT error (the hotter of the probe and the gas), the min/max selection of
        the speed command with the limit loops and fuel schedules, integrator tracking of the
        loops that did not win, and the observer (eq. 3.5) on the applied voltage."""
        s = self.s
        p = self.p
        t = self.t
        # the hotter of the probe and the gas (the lead) against the limit; the gas may pass
        # it by what the probe still reads under it, up to the transient allowance
        trim_v = p.trim_v_q24
        probe_dk = p.egt_limit_dk - s.egt_dk
        room_dk = clamp(probe_dk, 0, p.egt_gas_margin_dk)
        gas_dk = p.egt_limit_dk + room_dk - (s.egt_lead_q12 >> 12)
        e_dk = clamp(min(probe_dk, gas_dk), -EGT_ERROR_MAX_DK, EGT_ERROR_MAX_DK)
        v = t.v = select_voltage(
            s,
            p,
            sat32(trim_v + t.u),
            div_trunc(e_dk << 24, 10),
            t.egt_ok,
            t.n_q24,
            t.ctrl_rate,
        )
        u_applied = sub_sat(v, trim_v)
        if p.controller == CTRL_PID:
            pid_track(s, p, sat32(t.demand - t.n_q24), t.ctrl_rate, u_applied)
        elif p.controller == CTRL_PI:
            pi_track(s, p, sat32(t.demand - t.n_q24), t.n_q24, u_applied)
        if s.owner != OWNER_SPEED:  # the lag tracks what a limit applies (anti-windup)
            s.u_lag_q24 = u_applied
        observer_step(s, p, u_applied, t.dn, t.speed_ok)
        s.u_hist_q24[s.hist_idx] = u_applied

    def _stage_pump_driver(self) -> None:
        """The pump's duty from the measured supply (ecu.pump_driver), the starter and igniter:
        in RUN at the selected voltage; otherwise the sequencer's (a stop's cool-down, a start)
        with the models held where the engine is."""
        s = self.s
        p = self.p
        t = self.t
        seq = self.seq
        new_mode = t.new_mode
        faults = t.faults
        if new_mode == M.RUN:
            t.pump_mv = volts_q24_to_mv(t.v)
            t.duty = pump_duty(s, p, t.pump_mv, s.supply_mv)
            t.enable = 1
            if s.owner != OWNER_SPEED:
                faults |= F.LIMITER_ACTIVE
            if s.v_saturated:
                faults |= F.PUMP_SATURATED
        else:
            if new_mode == M.SHUTDOWN and p.start_on:
                Q.stop_step(s, p, t.n_rpm, s.egt_dk, seq)
            elif new_mode != M.ARMED:
                seq.v_q24 = 0  # a start that just ended: no fuel
            s.v_applied_q24 = seq.v_q24
            s.xm1_q24 = t.dn
            s.xm2_q24 = 0
            s.obs_n_q24 = t.dn
            s.obs_v_q24 = t.rate
            s.xh1_q24 = t.dn
            s.xh2_q24 = t.rate
            t.pump_mv = volts_q24_to_mv(seq.v_q24)
            t.duty = pump_duty(s, p, t.pump_mv, s.supply_mv) if t.pump_mv > 0 else 0
            t.enable = 1 if t.duty > 0 else 0
        if new_mode != M.ARMED and new_mode != M.SHUTDOWN:
            seq.starter_cpct = 0
            seq.igniter = 0
        s.starter_cpct = seq.starter_cpct
        s.igniter = seq.igniter
        t.faults = faults

    def _stage_actuator_tests(self, i: EcuInputs) -> None:
        """In OFF with no arm or stop request, a bench test function (ecu.actuator_tests): the
        igniter, the starter at its duty or the pump at its voltage, for the test's time."""
        s = self.s
        p = self.p
        t = self.t
        seq = self.seq
        allowed = 1 if (t.new_mode == M.OFF and not s.arm and not s.stop) else 0
        test = T.actuator_test_step(s, p, i.test_request, i.test_level, i.test_ms, allowed)
        if test == T.GLOW:
            seq.igniter = 1
        elif test == T.STARTER:
            seq.starter_cpct = clamp(s.test_level_held, 0, T.level_max(p, T.STARTER))
        elif test == T.PRIME:
            t.pump_mv = clamp(s.test_level_held, 0, T.level_max(p, T.PRIME))
            t.duty = pump_duty(s, p, t.pump_mv, s.supply_mv)
            t.enable = 1
        s.starter_cpct = seq.starter_cpct
        s.igniter = seq.igniter

    def _stage_health(self, i: EcuInputs) -> None:
        """Pump health, the fault word, the saturation count and the output record."""
        s = self.s
        p = self.p
        t = self.t
        o = self.out
        th = s.theta_q24
        faults = t.faults
        health = F.pump_health_pm(th[LAM], p.lambda_comm_q24)
        if health < p.health_alarm_pm:
            faults |= F.PUMP_HEALTH
        s.faults = faults
        sat_events = s.sat_events = sat32(s.sat_events + take_sat_events(self.sat_pending))
        o.tick = i.tick
        o.duty_cpct = t.duty
        o.pump_mv = t.pump_mv
        o.pump_enable = t.enable
        o.mode = t.new_mode
        o.fault_word = faults & 0xFFFF
        o.sat_events = sat_events
        o.ap21_q24 = th[AP21]
        o.ap22_q24 = th[AP22]
        o.lambda_q24 = th[LAM]
        o.theta21_q24 = th[TH1]
        o.theta22_q24 = th[TH2]
        o.kx1_q24 = th[KX1]
        o.kx2_q24 = th[KX2]
        o.kr_q24 = th[KR]
        o.kf1_q24 = th[KF1]
        o.kf2_q24 = th[KF2]
        o.pump_health_pm = health
        o.nref_cpct = _q24_to_cpct(s.xm1_q24 + p.trim_n_q24)
        o.n_cpct = _q24_to_cpct(t.n_q24)
        o.owner = s.owner
        seq = self.seq
        o.starter_cpct = seq.starter_cpct
        o.igniter = seq.igniter
        o.seq_state = s.seq_state
        o.seq_reason = s.seq_reason
        o.inputs_valid = t.inputs_valid

    def _stage_logbook(self) -> None:
        """The engine's logbook (ecu.logbook) from this tick's mode transition."""
        s = self.s
        t = self.t
        demand_lost = 1 if s.demand_age >= self.p.demand_shutdown_ticks else 0
        logbook_step(
            s,
            t.mode,
            t.new_mode,
            t.start_abort,
            demand_lost,
            t.trip_shutdown,
            self.out.n_cpct,
            self.p.rate_hz,
        )
