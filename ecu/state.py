"""The firmware's persistent state: one flat record of int32 fields (a C struct).

Scalars are slot attributes holding ints that every store saturates to int32; vectors are
``array('i')`` (C int32, which refuses out-of-range stores outright). Nothing here grows.
"""

from __future__ import annotations

from array import array
from typing import ClassVar

from ecu.params import LOG_ABORTS, RATE_BUF_LEN

# slow integrators (split accumulators): estimator (eq. 4.31), MRAC gains (eq. 5.16), PID integral
AP21 = 0  # A_p-hat row 2, column 1
AP22 = 1  # A_p-hat row 2, column 2
LAM = 2  # Lambda-hat
TH1 = 3  # Theta_f-hat row 2, column 1 (dN dV)
TH2 = 4  # Theta_f-hat row 2, column 2 (dN^2 dV)
KX1 = 5
KX2 = 6
KR = 7
KF1 = 8
KF2 = 9
PID_I = 10  # PID integrator (V), a slow integrator like the others
KB = 11  # MRAC bias gain (V): cancels the fuel-path bias of a changed pump (pump_scaling_on)
N_THETA = 12


class EcuState:
    """All firmware state, preallocated. Formats are in the names (see ecu.fixedpoint)."""

    FIELDS: ClassVar[tuple[str, ...]] = (
        # adaptive parameters: Q7.24 words and their 16-bit extensions
        "theta_q24", "theta_ext",
        # speed history for the central-difference rate (raw rpm), ring index and fill count
        "n_hist_rpm", "u_hist_q24", "hist_idx", "hist_fill",
        # identification model (eq. 4.7) state and last identification error e2
        "xh1_q24", "xh2_q24", "e2_q24",
        # fast-model observer (eq. 3.5) state, deviations from trim
        "obs_n_q24", "obs_v_q24",
        # speed-rate filter (ecu.rate_filter): speed and rate deviations, acceleration (Q15.16)
        "rf_n_q24", "rf_v_q24", "rf_a_q16",
        # reference model (eq. 5.18-5.19) state, deviations from trim; the MRAC's lagged command
        "xm1_q24", "xm2_q24", "u_lag_q24",
        # limit loops: previous errors (velocity form) and the applied pump voltage
        "egt_e_prev_q24", "acc_e_prev_q24", "dec_e_prev_q24", "nlim_e_prev_q24",
        # the EGT the limiter sees (lead on the thermocouple, 0.1 K in Q12; 0: no reading yet)
        "egt_lead_q12",
        # the applied voltage through the lag of the gas estimate (the EGT line's V_f)
        "egt_vf_q24",
        "v_applied_q24", "owner", "v_saturated", "line_owns",
        # last valid inputs held on frame loss
        "speed_rpm", "egt_dk", "supply_mv", "pump_ma", "demand_q24", "open_loop_q24",
        "arm", "stop",
        # persistence counters (ticks)
        "sensor_age", "analog_age", "demand_age",
        "speed_range_cnt", "speed_rate_cnt", "speed_stuck_cnt", "speed_stuck_v_q24",
        "egt_open_cnt", "egt_over_cnt", "overspeed_cnt", "flameout_cnt", "flame_egt_cnt",
        "pump_stall_cnt", "pump_dry_cnt",
        # speed sensor failed (latched) and how many speed samples the history holds
        "speed_failed", "speed_seen",
        # which sensors gave a valid reading since power-up (SEEN_* bits); a start or run that
        # ended with the arm request held waits for its release before the next (1)
        "inputs_seen", "rearm_wait",
        # start/stop sequencer (ecu.start_sequencer): state, abort reason, ticks in the state,
        # pump voltage, the light-off detector's reference EGT (0.1 K in Q8), relights since the
        # last start, commands of this tick, the start's EGT target on the day (0.1 K)
        "seq_state", "seq_reason", "seq_timer", "seq_v_q24", "seq_egt_ref_q8", "relights",
        "starter_cpct", "igniter", "seq_target_dk",
        # 1 / sqrt(theta) of corrected speed at the day's inlet temperature (ecu.inlet)
        "ncor_k_q24",
        # modes, faults, counters
        "mode", "faults", "sat_events", "ticks",
        # the engine's logbook (ecu.logbook): runs, seconds in RUN and the ticks of the second
        # under way, starts, aborts by reason, the last run's highest EGT (0.1 K) and speed
        # (0.01 %N), the last shutdown's reason, a run under way
        "log_runs", "log_run_time_s", "log_run_frac_ticks", "log_starts", "log_aborts",
        "log_last_max_egt_dk", "log_last_max_speed_cpct", "log_last_shutdown", "log_in_run",
        # bench test functions (ecu.actuator_tests): the test running (0 none), its ticks and
        # ms left, its level (0.01 % or mV), the last tick's request
        "test_active", "test_ticks_left", "test_time_left_ms", "test_level_held",
        "test_request_last",
    )  # fmt: skip
    __slots__ = FIELDS
    theta_q24: array
    theta_ext: array
    n_hist_rpm: array
    u_hist_q24: array
    hist_idx: int
    hist_fill: int
    xh1_q24: int
    xh2_q24: int
    e2_q24: int
    obs_n_q24: int
    obs_v_q24: int
    rf_n_q24: int
    rf_v_q24: int
    rf_a_q16: int
    xm1_q24: int
    xm2_q24: int
    u_lag_q24: int
    egt_e_prev_q24: int
    acc_e_prev_q24: int
    dec_e_prev_q24: int
    nlim_e_prev_q24: int
    egt_lead_q12: int
    egt_vf_q24: int
    v_applied_q24: int
    owner: int
    v_saturated: int
    line_owns: int
    speed_rpm: int
    egt_dk: int
    supply_mv: int
    pump_ma: int
    demand_q24: int
    open_loop_q24: int
    arm: int
    stop: int
    sensor_age: int
    analog_age: int
    demand_age: int
    speed_range_cnt: int
    speed_rate_cnt: int
    speed_stuck_cnt: int
    speed_stuck_v_q24: int
    egt_open_cnt: int
    egt_over_cnt: int
    overspeed_cnt: int
    flameout_cnt: int
    flame_egt_cnt: int
    pump_stall_cnt: int
    pump_dry_cnt: int
    speed_failed: int
    speed_seen: int
    inputs_seen: int
    rearm_wait: int
    seq_state: int
    seq_reason: int
    seq_timer: int
    seq_v_q24: int
    seq_egt_ref_q8: int
    relights: int
    starter_cpct: int
    igniter: int
    seq_target_dk: int
    ncor_k_q24: int
    mode: int
    faults: int
    sat_events: int
    ticks: int
    log_runs: int
    log_run_time_s: int
    log_run_frac_ticks: int
    log_starts: int
    log_aborts: array
    log_last_max_egt_dk: int
    log_last_max_speed_cpct: int
    log_last_shutdown: int
    log_in_run: int
    test_active: int
    test_ticks_left: int
    test_time_left_ms: int
    test_level_held: int
    test_request_last: int

    def __init__(self) -> None:
        self.theta_q24 = array("i", [0] * N_THETA)
        self.theta_ext = array("i", [0] * N_THETA)
        self.n_hist_rpm = array("i", [0] * RATE_BUF_LEN)
        self.u_hist_q24 = array("i", [0] * RATE_BUF_LEN)
        self.log_aborts = array("i", [0] * LOG_ABORTS)
        for name in self.FIELDS:
            if not hasattr(self, name):
                setattr(self, name, 0)
