"""The firmware's parameters: :class:`~ecu.params.EcuParams` compiled into Q-format constants.

``compile_params`` checks an ``EcuParams`` (refusing unsafe values with the field's name) and
converts it once, at start-up, into ``FirmwareParams``: the integer constants the firmware tick
reads (what a C build would hold in a ``const`` struct). This module is the only place where
engineering values become Q formats; it is configuration-time code, not part of the firmware
path.

Discretisation (all stated here, computed for the configured rate):
- identification model (eq. 4.7) and reference model (eq. 5.18-5.19): trapezoidal (Tustin) on
  the state with the input held over the step; stable at any rate for a Hurwitz A_m;
- parameter and gain update laws (eq. 4.31, 5.16), PID integrator, limit loops, fast-model
  observer: forward Euler with dt = 1 / rate_hz.
"""

from __future__ import annotations

import math
from typing import ClassVar

from ecu.fixedpoint import INT32_MAX, INT32_MIN, Q16, Q24, Q28
from ecu.inlet import day_target_dk, ncor_k_q24
from ecu.params import (
    CONTROLLERS,
    N_MAX_RPM,
    RATE_BUF_LEN,
    SCHED_N0_PCT,
    SCHED_STEP_PCT,
    EcuParams,
    ParamError,
    firmware_convention,
    validate,
)
from ecu.pi_design import PI_N0_PCT, PI_STEP_PCT, PiDesignError, PiPoint, design_schedule


def _q(x: float, frac_bits: int, field: str) -> int:
    """Round a float to a Q format with `frac_bits` fractional bits, refusing out-of-range."""
    v = round(x * (1 << frac_bits))
    if not INT32_MIN <= v <= INT32_MAX:
        raise ParamError(f"{field}={x!r} does not fit a 32-bit Q{31 - frac_bits}.{frac_bits}")
    return v


def _stored_q24(x: float) -> float:
    """``x`` as a Q24 parameter of the table stores it (the nearest multiple of 2**-24)."""
    return round(x * (1 << Q24)) / (1 << Q24)


def _tustin(a21: float, a22: float, dt: float) -> tuple[tuple[float, ...], tuple[float, float]]:
    """Trapezoidal discretisation of x' = [[0,1],[a21,a22]] x + [0,1] c with c held.

    Returns M = (I - dt/2 A)^-1 (I + dt/2 A) as (m11, m12, m21, m22) and h = (I - dt/2 A)^-1 dt
    column 2 as (h1, h2), so x[k+1] = M x[k] + h c[k].
    """
    h = dt / 2.0
    # L = I - h A = [[1, -h], [-h a21, 1 - h a22]]
    det = (1.0 - h * a22) - h * h * a21
    li = ((1.0 - h * a22) / det, h / det, h * a21 / det, 1.0 / det)  # inverse of L
    r = (1.0, h, h * a21, 1.0 + h * a22)  # R = I + h A
    m = (
        li[0] * r[0] + li[1] * r[2],
        li[0] * r[1] + li[1] * r[3],
        li[2] * r[0] + li[3] * r[2],
        li[2] * r[1] + li[3] * r[3],
    )
    return m, (li[1] * dt, li[3] * dt)


class FirmwareParams:
    """Integer constants of the firmware (a C ``const`` struct). Built by :func:`compile_params`."""

    FIELDS: ClassVar[tuple[str, ...]] = (
        "rate_hz", "controller", "dt_q24", "rpm_to_q24_k", "trim_n_q24", "trim_v_q24",
        "entry_v_q24",
        "am21_q24", "am22_q24", "idm11_q24", "idm12_q24", "idm21_q24", "idm22_q24",
        "idh1_q24", "idh2_q24",
        "g_a1_q28", "g_a2_q28", "g_lam_q28", "g_th1_q28", "g_th2_q28",
        "init_theta_q24",
        "lambda_comm_q24", "health_alarm_pm", "rate_half_window",
        "lambda_floor_on", "lambda_floor_q24", "dead_zone_on", "dead_zone_q24", "freeze_on",
        "adapt_band_q24",
        "p12_ratio_q24", "pump_scaling_on", "th_per_lam1_q28", "th_per_lam2_q28",
        "pump_v0_q24", "lam_comm_v0_q16", "g_b_q28",
        "ref_am21_q24", "ref_am22_q24", "ref_bm2_q24",
        "refm11_q24", "refm12_q24", "refm21_q24", "refm22_q24", "refh1_q24", "refh2_q24",
        "g_x1_q28", "g_x2_q28", "g_r_q28", "g_f1_q28", "g_f2_q28", "u_den_min_q24",
        "mrac_lag_c_q24",
        "pid_kp_q24", "pid_ki_dt_q28", "pid_kd_q24",
        "pi_n0_q24", "pi_step_q24", "pi_kp_q24", "pi_ki_dt_q28",
        "fuel_schedules_on", "sched_n0_q24", "sched_step_q24", "ncor_k_q24", "inlet_from_egt",
        "accel_line_q24", "decel_floor_q24", "accel_rate_q24", "pump_dead_q24", "sched_lam_lo_q24",
        "sched_lam_hi_q24",
        "idle_q24", "demand_max_q24",
        "limiters_on", "egt_limit_dk", "egt_gas_margin_dk", "egt_zero_fuel_dk",
        "egt_engage_q24", "rate_engage_q24",
        "n_limit_engage_q24",
        "egt_kp_q24", "egt_ki_dt_q24", "egt_lead_cf_q16", "egt_lead_ctc_q16", "egt_max_dk",
        "egt_max_ticks", "accel_max_q24", "decel_max_q24", "rate_kp_q24", "rate_ki_dt_q24",
        "n_limit_q24", "n_limit_kp_q24", "n_limit_ki_dt_q24", "overspeed_rpm", "overspeed_ticks",
        "flameout_rpm", "flameout_ticks", "flameout_egt_dk", "flameout_egt_ticks", "v_min_q24",
        "v_max_q24", "v_slew_q24",
        "duty_min_cpct", "duty_max_cpct", "supply_nominal_mv",
        "pump_stall_ma", "pump_trip_ma", "pump_stall_ticks", "pump_dry_base_ma",
        "pump_dry_ma_per_v", "pump_dry_min_q24", "pump_dry_ticks",
        "speed_valid_max_rpm", "speed_step_max_rpm", "speed_fault_ticks", "speed_stuck_ticks",
        "speed_stuck_dv_q24", "egt_open_high_dk", "egt_open_low_dk", "egt_fault_ticks",
        "egt_fail_demand_q24", "obs_l1_dt_q24", "obs_l2_dt_q24",
        "rate_filter_on", "rf_k1_q24", "rf_k2_q24", "rf_k3_q24",
        "demand_hold_ticks", "demand_shutdown_ticks", "sensor_loss_ticks", "analog_loss_ticks",
        "run_entry_rpm", "shutdown_done_rpm",
        "start_on", "seq_start_cpct", "seq_purge_ticks", "seq_ign_rpm", "seq_spinup_ticks",
        "seq_ign_v0_q24", "seq_ign_v_step_q24", "seq_ign_v_max_q24", "seq_light_rise_dk",
        "seq_light_track_q8",
        "seq_ign_ticks", "seq_igniter_hold_ticks", "seq_starter_step_cpct", "seq_ramp_v_step_q24",
        "seq_accel_q24",
        "seq_egt_target_dk", "seq_hot_dk", "seq_egt_cap_dk", "seq_day_target_dk",
        "seq_cutoff_rpm", "seq_ramp_ticks", "seq_idle_rpm",
        "seq_stabilise_ticks", "seq_relight_max", "seq_cool_cpct", "seq_cool_egt_dk",
        "seq_cool_rearm_dk", "seq_cool_rpm", "seq_cool_ticks", "seq_soak_ticks",
    )  # fmt: skip
    __slots__ = FIELDS
    rate_hz: int
    controller: int
    dt_q24: int
    rpm_to_q24_k: int
    trim_n_q24: int
    trim_v_q24: int
    entry_v_q24: int
    am21_q24: int
    am22_q24: int
    idm11_q24: int
    idm12_q24: int
    idm21_q24: int
    idm22_q24: int
    idh1_q24: int
    idh2_q24: int
    g_a1_q28: int
    g_a2_q28: int
    g_lam_q28: int
    g_th1_q28: int
    g_th2_q28: int
    init_theta_q24: tuple[int, ...]
    lambda_comm_q24: int
    health_alarm_pm: int
    rate_half_window: int
    lambda_floor_on: int
    lambda_floor_q24: int
    dead_zone_on: int
    dead_zone_q24: int
    freeze_on: int
    adapt_band_q24: int
    p12_ratio_q24: int
    pump_scaling_on: int
    th_per_lam1_q28: int
    th_per_lam2_q28: int
    pump_v0_q24: int
    lam_comm_v0_q16: int
    g_b_q28: int
    ref_am21_q24: int
    ref_am22_q24: int
    ref_bm2_q24: int
    refm11_q24: int
    refm12_q24: int
    refm21_q24: int
    refm22_q24: int
    refh1_q24: int
    refh2_q24: int
    g_x1_q28: int
    g_x2_q28: int
    g_r_q28: int
    g_f1_q28: int
    g_f2_q28: int
    u_den_min_q24: int
    mrac_lag_c_q24: int
    pid_kp_q24: int
    pid_ki_dt_q28: int
    pid_kd_q24: int
    pi_n0_q24: int
    pi_step_q24: int
    pi_kp_q24: tuple[int, ...]
    pi_ki_dt_q28: tuple[int, ...]
    fuel_schedules_on: int
    sched_n0_q24: int
    sched_step_q24: int
    ncor_k_q24: int
    inlet_from_egt: int
    accel_line_q24: tuple[int, ...]
    decel_floor_q24: tuple[int, ...]
    accel_rate_q24: tuple[int, ...]
    pump_dead_q24: int
    sched_lam_lo_q24: int
    sched_lam_hi_q24: int
    idle_q24: int
    demand_max_q24: int
    limiters_on: int
    egt_limit_dk: int
    egt_gas_margin_dk: int
    egt_zero_fuel_dk: int
    egt_engage_q24: int
    rate_engage_q24: int
    n_limit_engage_q24: int
    egt_kp_q24: int
    egt_ki_dt_q24: int
    egt_lead_cf_q16: int
    egt_lead_ctc_q16: int
    egt_max_dk: int
    egt_max_ticks: int
    accel_max_q24: int
    decel_max_q24: int
    rate_kp_q24: int
    rate_ki_dt_q24: int
    n_limit_q24: int
    n_limit_kp_q24: int
    n_limit_ki_dt_q24: int
    overspeed_rpm: int
    overspeed_ticks: int
    flameout_rpm: int
    flameout_ticks: int
    flameout_egt_dk: int
    flameout_egt_ticks: int
    v_min_q24: int
    v_max_q24: int
    v_slew_q24: int
    duty_min_cpct: int
    duty_max_cpct: int
    supply_nominal_mv: int
    pump_stall_ma: int
    pump_trip_ma: int
    pump_stall_ticks: int
    pump_dry_base_ma: int
    pump_dry_ma_per_v: int
    pump_dry_min_q24: int
    pump_dry_ticks: int
    speed_valid_max_rpm: int
    speed_step_max_rpm: int
    speed_fault_ticks: int
    speed_stuck_ticks: int
    speed_stuck_dv_q24: int
    egt_open_high_dk: int
    egt_open_low_dk: int
    egt_fault_ticks: int
    egt_fail_demand_q24: int
    obs_l1_dt_q24: int
    obs_l2_dt_q24: int
    rate_filter_on: int
    rf_k1_q24: int
    rf_k2_q24: int
    rf_k3_q24: int
    demand_hold_ticks: int
    demand_shutdown_ticks: int
    sensor_loss_ticks: int
    analog_loss_ticks: int
    run_entry_rpm: int
    shutdown_done_rpm: int
    start_on: int
    seq_start_cpct: int
    seq_purge_ticks: int
    seq_ign_rpm: int
    seq_spinup_ticks: int
    seq_ign_v0_q24: int
    seq_ign_v_step_q24: int
    seq_ign_v_max_q24: int
    seq_light_rise_dk: int
    seq_light_track_q8: int
    seq_ign_ticks: int
    seq_igniter_hold_ticks: int
    seq_starter_step_cpct: int
    seq_ramp_v_step_q24: int
    seq_accel_q24: int
    seq_egt_target_dk: int
    seq_hot_dk: int
    seq_egt_cap_dk: int
    seq_day_target_dk: int
    seq_cutoff_rpm: int
    seq_ramp_ticks: int
    seq_idle_rpm: int
    seq_stabilise_ticks: int
    seq_relight_max: int
    seq_cool_cpct: int
    seq_cool_egt_dk: int
    seq_cool_rearm_dk: int
    seq_cool_rpm: int
    seq_cool_ticks: int
    seq_soak_ticks: int

    def __init__(self, **values: object) -> None:
        missing = set(self.FIELDS) - set(values)
        if missing:
            raise ParamError(f"FirmwareParams: missing {sorted(missing)}")
        for k, v in values.items():
            setattr(self, k, v)


def pi_schedule(p: EcuParams) -> tuple[PiPoint, ...]:
    """The PI baseline's gains at its scheduling speeds (ecu.pi_design), from the commissioned
    model in the firmware's convention; a model that admits none is refused, naming the field."""
    q = firmware_convention(p)
    try:
        return design_schedule(
            q.trim_n_pct,
            q.init_ap_row2,
            q.init_lambda,
            q.init_theta_row2,
            q.pi_bandwidth,
            q.pi_phase_margin,
        )
    except PiDesignError as exc:
        raise ParamError(f"pi_bandwidth={p.pi_bandwidth!r}: {exc}") from None


def compile_params(p: EcuParams) -> FirmwareParams:
    """Validate ``p`` and convert it to the firmware's integer constants."""
    validate(p)
    p = firmware_convention(p)
    validate(p)  # the gains as the firmware applies them
    hz = p.rate_hz
    dt = 1.0 / hz

    def ticks(seconds: float) -> int:
        return max(1, round(seconds * hz))

    def rpm(pct: float) -> int:
        return round(pct * N_MAX_RPM / 100.0)

    inlet_ck = round(p.inlet_temp_k * 100.0)
    cap_dk = round((p.start_egt_limit_k - p.start_egt_margin_k) * 10.0)

    idm, idh = _tustin(p.am_row2[0], p.am_row2[1], dt)
    ref_a21, ref_a22 = -(p.ref_wn**2), -2.0 * p.ref_zeta * p.ref_wn
    refm, refh = _tustin(ref_a21, ref_a22, dt)
    m = max(1, round(p.rate_window_s * hz / 2.0))  # half window of the central difference
    c = 1.0 - math.exp(-p.rate_filter_bw * dt)  # rate filter: triple pole at z = 1 - c
    if 2 * m + 1 > RATE_BUF_LEN:
        raise ParamError(f"rate_window_s={p.rate_window_s!r}: window too long for the buffer")
    pct_per_rpm = 100.0 / N_MAX_RPM
    # dead zone on e2: the central-difference rate noise from sensor noise sigma_N is
    # sqrt(2) sigma_N / (2 m dt); quantisation adds 1/sqrt(12) count per sample.
    sigma_n = math.hypot(p.speed_noise_rpm, 1.0 / math.sqrt(12.0)) * pct_per_rpm
    sigma_rate = math.sqrt(2.0) * sigma_n / (2.0 * m * dt)
    g_pdt = p.p22 * dt
    # K_b matching the initial Lambda-hat: Lambda K_b + (Lambda - Lambda_c) V0 = 0 (eq. 5.14 form)
    # pump voltage at trim above the dead voltage, from the values as the parameter table stores
    # them (Q24): the C slave derives these words from the stored raws after a write
    v0_pump = _stored_q24(p.trim_v) - _stored_q24(p.pump_dead_v)
    kb0 = v0_pump * (p.lambda_commissioned / p.init_lambda - 1.0) if p.pump_scaling_on else 0.0
    th_scale = p.init_lambda / p.lambda_commissioned if p.pump_scaling_on else 1.0
    pi = pi_schedule(p)
    return FirmwareParams(
        rate_hz=hz,
        controller=CONTROLLERS.index(p.controller),
        dt_q24=_q(dt, Q24, "rate_hz"),
        # rpm -> Q7.24 %N: (rpm * K) >> 16 with K = 2^40 / 1125 (exact to 2^-16 LSB)
        rpm_to_q24_k=_q(pct_per_rpm, Q24 + 16, "n_max_rpm"),
        trim_n_q24=_q(p.trim_n_pct, Q24, "trim_n_pct"),
        trim_v_q24=_q(p.trim_v, Q24, "trim_v"),
        entry_v_q24=_q(p.entry_v, Q24, "entry_v"),
        am21_q24=_q(p.am_row2[0], Q24, "am_row2"),
        am22_q24=_q(p.am_row2[1], Q24, "am_row2"),
        idm11_q24=_q(idm[0], Q24, "am_row2"),
        idm12_q24=_q(idm[1], Q24, "am_row2"),
        idm21_q24=_q(idm[2], Q24, "am_row2"),
        idm22_q24=_q(idm[3], Q24, "am_row2"),
        idh1_q24=_q(idh[0], Q24, "am_row2"),
        idh2_q24=_q(idh[1], Q24, "am_row2"),
        g_a1_q28=_q(p.gamma_a[0] * g_pdt, Q28, "gamma_a"),
        g_a2_q28=_q(p.gamma_a[1] * g_pdt, Q28, "gamma_a"),
        g_lam_q28=_q(p.gamma_lambda * g_pdt, Q28, "gamma_lambda"),
        g_th1_q28=_q(p.gamma_theta[0] * g_pdt, Q28, "gamma_theta"),
        g_th2_q28=_q(p.gamma_theta[1] * g_pdt, Q28, "gamma_theta"),
        init_theta_q24=tuple(
            _q(v, Q24, name)
            for v, name in (
                (p.init_ap_row2[0], "init_ap_row2"),
                (p.init_ap_row2[1], "init_ap_row2"),
                (p.init_lambda, "init_lambda"),
                (p.init_theta_row2[0] * th_scale, "init_theta_row2"),
                (p.init_theta_row2[1] * th_scale, "init_theta_row2"),
                (p.init_kx[0], "init_kx"),
                (p.init_kx[1], "init_kx"),
                (p.init_kr, "init_kr"),
                (p.init_kf[0], "init_kf"),
                (p.init_kf[1], "init_kf"),
                (0.0, "pid_ki"),  # PID integrator starts at zero
                (kb0, "init_lambda"),  # K_b: the bias gain matching init_lambda
            )
        ),
        lambda_comm_q24=_q(p.lambda_commissioned, Q24, "lambda_commissioned"),
        health_alarm_pm=round(p.pump_health_alarm * 1000.0),
        rate_half_window=m,
        lambda_floor_on=int(p.lambda_floor_on),
        lambda_floor_q24=_q(p.lambda_floor, Q24, "lambda_floor"),
        dead_zone_on=int(p.dead_zone_on),
        dead_zone_q24=_q(p.dead_zone_sigmas * sigma_rate, Q24, "speed_noise_rpm"),
        freeze_on=int(p.freeze_on),
        adapt_band_q24=_q(p.adapt_band_pct, Q24, "adapt_band_pct"),
        p12_ratio_q24=_q(p.p12 / p.p22, Q24, "p12"),
        pump_scaling_on=int(p.pump_scaling_on),
        th_per_lam1_q28=_q(p.init_theta_row2[0] / p.lambda_commissioned, Q28, "init_theta_row2"),
        th_per_lam2_q28=_q(p.init_theta_row2[1] / p.lambda_commissioned, Q28, "init_theta_row2"),
        pump_v0_q24=_q(v0_pump, Q24, "pump_dead_v"),
        lam_comm_v0_q16=_q(_stored_q24(p.lambda_commissioned) * v0_pump, 16, "lambda_commissioned"),
        g_b_q28=_q(p.gamma_b * dt, Q28, "gamma_b"),
        ref_am21_q24=_q(ref_a21, Q24, "ref_wn"),
        ref_am22_q24=_q(ref_a22, Q24, "ref_zeta"),
        ref_bm2_q24=_q(p.ref_wn**2, Q24, "ref_wn"),
        refm11_q24=_q(refm[0], Q24, "ref_wn"),
        refm12_q24=_q(refm[1], Q24, "ref_wn"),
        refm21_q24=_q(refm[2], Q24, "ref_wn"),
        refm22_q24=_q(refm[3], Q24, "ref_wn"),
        refh1_q24=_q(refh[0] * p.ref_wn**2, Q24, "ref_wn"),
        refh2_q24=_q(refh[1] * p.ref_wn**2, Q24, "ref_wn"),
        g_x1_q28=_q(p.gamma_x[0] * dt, Q28, "gamma_x"),
        g_x2_q28=_q(p.gamma_x[1] * dt, Q28, "gamma_x"),
        g_r_q28=_q(p.gamma_r * dt, Q28, "gamma_r"),
        g_f1_q28=_q(p.gamma_f[0] * dt, Q28, "gamma_f"),
        g_f2_q28=_q(p.gamma_f[1] * dt, Q28, "gamma_f"),
        u_den_min_q24=_q(p.u_den_min, Q24, "u_den_min"),
        mrac_lag_c_q24=_q(dt / (p.mrac_cmd_lag_s + dt), Q24, "mrac_cmd_lag_s"),
        pid_kp_q24=_q(p.pid_kp, Q24, "pid_kp"),
        pid_ki_dt_q28=_q(p.pid_ki * dt, Q28, "pid_ki"),
        pid_kd_q24=_q(p.pid_kd, Q24, "pid_kd"),
        pi_n0_q24=_q(PI_N0_PCT, Q24, "pi_bandwidth"),
        pi_step_q24=_q(PI_STEP_PCT, Q24, "pi_bandwidth"),
        pi_kp_q24=tuple(_q(pt.kp, Q24, "pi_bandwidth") for pt in pi),
        pi_ki_dt_q28=tuple(_q(pt.ki * dt, Q28, "pi_bandwidth") for pt in pi),
        fuel_schedules_on=int(p.fuel_schedules_on),
        sched_n0_q24=_q(SCHED_N0_PCT, Q24, "accel_line_v"),
        sched_step_q24=_q(SCHED_STEP_PCT, Q24, "accel_line_v"),
        ncor_k_q24=ncor_k_q24(inlet_ck),
        inlet_from_egt=int(p.inlet_from_egt),
        accel_line_q24=tuple(_q(v, Q24, "accel_line_v") for v in p.accel_line_v),
        accel_rate_q24=tuple(_q(r, Q24, "accel_rate_pct_s") for r in p.accel_rate_pct_s),
        decel_floor_q24=tuple(_q(v, Q24, "decel_floor_v") for v in p.decel_floor_v),
        pump_dead_q24=_q(p.pump_dead_v, Q24, "pump_dead_v"),
        sched_lam_lo_q24=_q(
            p.schedule_pump_range[0] * p.lambda_commissioned, Q24, "schedule_pump_range"
        ),
        sched_lam_hi_q24=_q(
            p.schedule_pump_range[1] * p.lambda_commissioned, Q24, "schedule_pump_range"
        ),
        idle_q24=_q(p.idle_pct, Q24, "idle_pct"),
        demand_max_q24=_q(p.demand_max_pct, Q24, "demand_max_pct"),
        limiters_on=int(p.limiters_on),
        egt_limit_dk=round(p.egt_limit_k * 10.0),
        egt_gas_margin_dk=round(p.egt_gas_margin_k * 10.0),
        egt_zero_fuel_dk=round(p.egt_zero_fuel_k * 10.0),
        egt_engage_q24=_q(p.egt_engage_k, Q24, "egt_engage_k"),
        rate_engage_q24=_q(p.rate_engage_pct_s, Q24, "rate_engage_pct_s"),
        n_limit_engage_q24=_q(p.n_limit_engage_pct, Q24, "n_limit_engage_pct"),
        egt_kp_q24=_q(p.egt_kp, Q24, "egt_kp"),
        egt_ki_dt_q24=_q(p.egt_ki * dt, Q24, "egt_ki"),
        egt_lead_cf_q16=_q(dt / (p.egt_lead_filter_s + dt), Q16, "egt_lead_filter_s"),
        egt_lead_ctc_q16=_q(p.egt_lead_tau_s / (p.egt_lead_filter_s + dt), Q16, "egt_lead_tau_s"),
        egt_max_dk=round(p.egt_max_k * 10.0),
        egt_max_ticks=ticks(p.egt_max_time_s),
        accel_max_q24=_q(p.accel_max_pct_s, Q24, "accel_max_pct_s"),
        decel_max_q24=_q(p.decel_max_pct_s, Q24, "decel_max_pct_s"),
        rate_kp_q24=_q(p.rate_kp, Q24, "rate_kp"),
        rate_ki_dt_q24=_q(p.rate_ki * dt, Q24, "rate_ki"),
        n_limit_q24=_q(p.n_limit_pct, Q24, "n_limit_pct"),
        n_limit_kp_q24=_q(p.n_limit_kp, Q24, "n_limit_kp"),
        n_limit_ki_dt_q24=_q(p.n_limit_ki * dt, Q24, "n_limit_ki"),
        overspeed_rpm=rpm(p.overspeed_pct),
        overspeed_ticks=ticks(p.overspeed_time_s),
        flameout_rpm=rpm(p.idle_pct * (1.0 - p.flameout_margin)),
        flameout_ticks=ticks(p.flameout_time_s),
        flameout_egt_dk=round(p.flameout_egt_k * 10.0),
        flameout_egt_ticks=ticks(p.flameout_egt_time_s),
        v_min_q24=_q(p.v_min, Q24, "v_min"),
        v_max_q24=_q(p.v_max, Q24, "v_max"),
        v_slew_q24=_q(p.v_slew_v_s * dt, Q24, "v_slew_v_s"),
        duty_min_cpct=round(p.duty_min * 10000.0),
        duty_max_cpct=round(p.duty_max * 10000.0),
        supply_nominal_mv=round(p.supply_nominal_v * 1000.0),
        pump_stall_ma=round(p.pump_stall_ma),
        pump_stall_ticks=ticks(p.pump_stall_time_s),
        pump_trip_ma=round(p.pump_trip_ma),
        pump_dry_base_ma=round(p.pump_dry_base_ma),
        pump_dry_ma_per_v=round(p.pump_dry_ma_per_v),
        pump_dry_min_q24=_q(p.pump_dry_min_v, Q24, "pump_dry_min_v"),
        pump_dry_ticks=ticks(p.pump_dry_time_s),
        speed_valid_max_rpm=round(p.speed_valid_max_rpm),
        speed_step_max_rpm=max(1, round(rpm(p.speed_rate_max_pct_s) * dt)),
        speed_fault_ticks=ticks(p.speed_fault_time_s),
        speed_stuck_ticks=ticks(p.speed_stuck_time_s),
        speed_stuck_dv_q24=_q(p.speed_stuck_dv, Q24, "speed_stuck_dv"),
        egt_open_high_dk=round(p.egt_open_high_k * 10.0),
        egt_open_low_dk=round(p.egt_open_low_k * 10.0),
        egt_fault_ticks=ticks(p.egt_fault_time_s),
        egt_fail_demand_q24=_q(p.egt_fail_demand_max_pct, Q24, "egt_fail_demand_max_pct"),
        obs_l1_dt_q24=_q(p.observer_l[0] * dt, Q24, "observer_l"),
        obs_l2_dt_q24=_q(p.observer_l[1] * dt, Q24, "observer_l"),
        rate_filter_on=int(p.rate_filter_on),
        rf_k1_q24=_q(3.0 * c, Q24, "rate_filter_bw"),
        rf_k2_q24=_q(3.0 * c * c / dt, Q24, "rate_filter_bw"),
        rf_k3_q24=_q(c**3 / (dt * dt), Q24, "rate_filter_bw"),
        demand_hold_ticks=ticks(p.demand_hold_s),
        demand_shutdown_ticks=ticks(p.demand_shutdown_s),
        sensor_loss_ticks=ticks(p.sensor_loss_s),
        analog_loss_ticks=ticks(p.analog_loss_s),
        run_entry_rpm=rpm(p.run_entry_pct),
        shutdown_done_rpm=rpm(p.shutdown_done_pct),
        start_on=int(p.start_on),
        seq_start_cpct=round(p.start_duty * 10000.0),
        seq_purge_ticks=ticks(p.start_purge_s),
        seq_ign_rpm=rpm(p.start_ignition_pct),
        seq_spinup_ticks=ticks(p.start_spinup_timeout_s),
        seq_ign_v0_q24=_q(p.start_ign_v0, Q24, "start_ign_v0"),
        seq_ign_v_step_q24=_q(p.start_ign_v_rate * dt, Q24, "start_ign_v_rate"),
        seq_ign_v_max_q24=_q(p.start_ign_v_max, Q24, "start_ign_v_max"),
        seq_light_rise_dk=round(p.start_light_rise_k * 10.0),
        seq_light_track_q8=max(1, round(p.start_light_track_k_s * 10.0 * 256.0 * dt)),
        seq_ign_ticks=ticks(p.start_ignition_timeout_s),
        seq_igniter_hold_ticks=ticks(p.start_igniter_hold_s),
        seq_starter_step_cpct=max(
            1, round((1.0 - p.start_duty) * 10000.0 / ticks(p.start_starter_ramp_s))
        ),
        seq_ramp_v_step_q24=_q(p.start_ramp_v_rate * dt, Q24, "start_ramp_v_rate"),
        seq_accel_q24=_q(p.start_accel_pct_s, Q24, "start_accel_pct_s"),
        seq_egt_target_dk=round(p.start_egt_target_k * 10.0),
        seq_hot_dk=round(p.start_egt_limit_k * 10.0),
        seq_egt_cap_dk=cap_dk,
        seq_day_target_dk=day_target_dk(round(p.start_egt_target_k * 10.0), cap_dk, inlet_ck),
        seq_cutoff_rpm=rpm(p.start_cutoff_pct),
        seq_ramp_ticks=ticks(p.start_ramp_timeout_s),
        seq_idle_rpm=rpm(p.start_idle_pct),
        seq_stabilise_ticks=ticks(p.start_stabilise_timeout_s),
        seq_relight_max=p.relight_max,
        seq_cool_cpct=round(p.cool_duty * 10000.0),
        seq_cool_egt_dk=round(p.cool_egt_k * 10.0),
        seq_cool_rearm_dk=round(p.cool_rearm_k * 10.0),
        seq_cool_rpm=rpm(p.cool_speed_pct),
        seq_cool_ticks=ticks(p.cool_timeout_s),
        seq_soak_ticks=ticks(p.cool_soak_s),
    )
