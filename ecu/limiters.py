"""Limit protection: limit loops and fuel schedules combined with the speed loop by min/max
selection.

    V = max( V_floor(Nc), V_decel, min( V_speed, V_egt, V_egt_line, V_accel, V_nlimit,
    V_line(Nc) ) ), then [V_min, V_max] and slew.

V_egt_line (egt_line_v, with the fuel schedules) is this engine's own EGT-limited acceleration
line at its present speed, from the gas estimate and the applied voltage: it owns as the EGT loop
does (OWNER_EGT).

V_accel holds the shaft's acceleration under the acceleration schedule Ndot_max(Nc) (and under
accel_max_pct_s); V_decel its deceleration under decel_max_pct_s.

V_line and V_floor are the fuel schedules (acceleration line, deceleration floor) against
corrected speed Nc, moved with the estimated pump in the safe direction only (the line down for a
stronger pump, the floor up for a weaker one: an estimate thrown off by a transient or by the fast
model's distance from its trim speed never makes the engine hotter or leaner; ecu.params:
accel_line_v, decel_floor_v);
they own the command as the acceleration and deceleration limits do (OWNER_ACCEL, OWNER_DECEL).

Each limit loop is a PI in velocity (incremental) form on its own error (margin to its limit),
started from the voltage applied last tick:  V_loop = V_applied[k-1] + Kp (e[k] - e[k-1]) +
Ki dt e[k]  (forward Euler). A loop that is not selected therefore tracks the applied voltage by
construction (integrator tracking) and takes over bumplessly as its margin shrinks. A loop joins
the selection only inside its engagement band (margin below ``*_engage``); far from its limit it
would otherwise act as a voltage rate limit and own every large step of the speed loop. A loop
that did not own the command last tick joins on its integral part alone: its P part acts on the
change of its error, at a steady operating point inside the band the sensors' noise (the EGT
lead's, the differentiated speed's), and the min-select would take each of its downward kicks
and none of its upward ones (at maximum demand the nominal engine, 26 K inside the EGT band and
at the acceleration schedule's 5 %N/s floor, stalled at 98.5 %N). Once it owns, its P part
acts. The speed loop's own tracking is done by the controller (PID back-calculation; MRAC has no
integrator).
"""

from __future__ import annotations

from ecu.firmware_params import FirmwareParams
from ecu.fixedpoint import add_sat, clamp, div_trunc, mul_q24, sat32, sub_sat
from ecu.state import LAM, EcuState
from ecu.tables import interp_uniform

OWNER_SPEED = 0
OWNER_EGT = 1
OWNER_ACCEL = 2
OWNER_NLIMIT = 3
OWNER_DECEL = 4


def egt_lead_step(s: EcuState, p: FirmwareParams, egt_dk: int) -> None:
    """The gas temperature from the thermocouple's reading: the lead (T_tc s + 1)/(T_f s + 1)
    by backward Euler,  y[k] = y[k-1] + c_f (x[k] - y[k-1]) + c_tc (x[k] - x[k-1]),  with
    c_f = dt/(T_f + dt) and c_tc = T_tc/(T_f + dt) in Q16; y in 0.1 K Q19.12, which holds the
    lead's largest output (gain up to 20 on a full-scale step) without saturating; exact in
    steady state. Called with each valid reading before s.egt_dk (x[k-1]) takes it."""
    x_q12 = egt_dk << 12
    y = s.egt_lead_q12
    if y == 0:  # the first reading: no history to lead on
        s.egt_lead_q12 = sat32(x_q12)
        return
    y += (p.egt_lead_cf_q16 * (x_q12 - y)) >> 16
    s.egt_lead_q12 = sat32(y + ((p.egt_lead_ctc_q16 * (egt_dk - s.egt_dk)) >> 4))


def schedule_at(s: EcuState, p: FirmwareParams, table: tuple[int, ...], n_q24: int) -> int:
    """A schedule's table at corrected speed N / sqrt(theta) for the speed n_q24 (Q7.24), theta
    of the day's inlet temperature (ecu.inlet)."""
    n_cor = mul_q24(n_q24, s.ncor_k_q24)
    return interp_uniform(table, p.sched_n0_q24, p.sched_step_q24, n_cor)


def schedule_v(
    s: EcuState, p: FirmwareParams, table: tuple[int, ...], n_q24: int, lam_lo: int, lam_hi: int
) -> int:
    """A fuel schedule's pump voltage at speed n_q24 (Q7.24): the table at corrected speed, for
    the pump as estimated: V_d + (V - V_d) Lambda_c / Lambda-hat delivers the table's fuel, with
    Lambda-hat taken within [lam_lo, lam_hi] (Q24)."""
    v = schedule_at(s, p, table, n_q24)
    if not p.pump_scaling_on:
        return v
    lam = clamp(s.theta_q24[LAM], lam_lo, lam_hi)
    v_d = p.pump_dead_q24
    return sat32(v_d + div_trunc((v - v_d) * p.lambda_comm_q24, lam))


def pump_from_start(s: EcuState, p: FirmwareParams, n_q24: int, v_q24: int) -> None:
    """At the hand-over from a start at speed n_q24 and pump voltage v_q24: a start that needed
    more than the commissioned pump's acceleration line has a weaker pump (no estimate exists
    yet, and none adapts at idle), so Lambda-hat starts at Lambda_c (V_line - V_d) / (V - V_d),
    the pump for which the line passes through V (an upper bound on its weakness: V carried the
    start's acceleration), and the line with it. The start's own cap, the line of the weakest
    pump the schedules accept, keeps it within schedule_pump_range."""
    line = schedule_at(s, p, p.accel_line_q24, n_q24)
    if v_q24 > line > p.pump_dead_q24:
        lam = div_trunc((line - p.pump_dead_q24) * p.lambda_comm_q24, v_q24 - p.pump_dead_q24)
        lam = max(lam, p.sched_lam_lo_q24)
        s.theta_q24[LAM] = lam
        s.theta_ext[LAM] = 0


def egt_line_v(s: EcuState, p: FirmwareParams, v_prev: int) -> int | None:
    """This engine's EGT-limited acceleration line at its present speed: at frozen speed the gas
    rises linearly with the fuel from T_0 = egt_zero_fuel at none, so the voltage that puts it at
    the limit is  V_d + (V_f - V_d) (T_lim - T_0) / (T_gas - T_0),  T_gas the gas estimate (the
    lead) and V_f the applied voltage through the same lag (the lead's filter c_f), so that the
    two belong together in a transient. None while the gas is under a quarter of the limit's
    rise (an engine far from it, or not lit: no cap, and the ratio stays under 4). Updates V_f."""
    vf = s.egt_vf_q24
    vf = s.egt_vf_q24 = sat32(vf + ((p.egt_lead_cf_q16 * (v_prev - vf)) >> 16))
    zero_dk = p.egt_zero_fuel_dk
    rise_dk = (s.egt_lead_q12 >> 12) - zero_dk
    limit_rise_dk = p.egt_limit_dk - zero_dk
    v_d = p.pump_dead_q24
    if not zero_dk or 4 * rise_dk < limit_rise_dk or vf <= v_d:
        return None
    return sat32(v_d + div_trunc((vf - v_d) * limit_rise_dk, rise_dk))


def _loop(v_prev: int, e: int, e_prev: int, kp_q24: int, ki_dt_q24: int, owns: bool) -> int:
    """A limit loop's voltage, its P part only while it owns the command."""
    p_part = (kp_q24 * (e - e_prev)) >> 24 if owns else 0
    return sat32(v_prev + p_part + ((ki_dt_q24 * e) >> 24))


def select_voltage(
    s: EcuState,
    p: FirmwareParams,
    v_speed: int,
    egt_err_q24: int,
    egt_ok: int,
    n_q24: int,
    rate_q24: int,
) -> int:
    """Min/max selection, voltage limits and slew; sets s.owner, s.v_saturated, s.line_owns (the
    acceleration line, not its rate loop, owns) and s.v_applied_q24."""
    if not p.limiters_on:
        s.owner = OWNER_SPEED
        s.v_saturated = 0
        s.line_owns = 0
        s.v_applied_q24 = v_speed
        return v_speed
    v_prev = s.v_applied_q24
    v, owner = egt_limits(s, p, v_prev, v_speed, egt_err_q24, egt_ok)
    v, owner, by_line = accel_limits(s, p, v_prev, v, owner, n_q24, rate_q24)
    v, owner = decel_limits(s, p, v_prev, v, owner, n_q24, rate_q24)
    v_lim = clamp(v, p.v_min_q24, p.v_max_q24)
    s.v_saturated = 1 if v_lim != v else 0  # at a voltage limit (the slew alone is not)
    v_lim = clamp(v_lim, v_prev - p.v_slew_q24, v_prev + p.v_slew_q24)
    s.owner = owner
    s.line_owns = by_line if owner == OWNER_ACCEL else 0
    s.v_applied_q24 = v_lim
    return v_lim


def egt_limits(
    s: EcuState, p: FirmwareParams, v_prev: int, v_speed: int, egt_err_q24: int, egt_ok: int
) -> tuple[int, int]:
    """The speed control's voltage under the EGT limit loop and the EGT line: (v, owner)."""
    v, owner = v_speed, OWNER_SPEED
    if egt_ok:
        e = egt_err_q24
        if e < p.egt_engage_q24:
            v_egt = _loop(
                v_prev, e, s.egt_e_prev_q24, p.egt_kp_q24, p.egt_ki_dt_q24, s.owner == OWNER_EGT
            )
            if v_egt < v:
                v, owner = v_egt, OWNER_EGT
        s.egt_e_prev_q24 = e
    v_egt_line = egt_line_v(s, p, v_prev) if p.fuel_schedules_on else None
    if egt_ok and v_egt_line is not None and v_egt_line < v:
        v, owner = v_egt_line, OWNER_EGT
    return v, owner


def accel_limits(
    s: EcuState, p: FirmwareParams, v_prev: int, v: int, owner: int, n_q24: int, rate_q24: int
) -> tuple[int, int, int]:
    """``v`` under the acceleration rate loop, the overspeed loop and the acceleration line:
    (v, owner, 1 if the line owns)."""
    by_line = 0
    rate_owned = s.owner == OWNER_ACCEL and not s.line_owns  # the rate loop, not the line
    ndot_max = p.accel_max_q24
    if p.fuel_schedules_on:  # the acceleration schedule, under the overall limit
        ndot_max = min(ndot_max, schedule_at(s, p, p.accel_rate_q24, n_q24))
    e = sub_sat(ndot_max, rate_q24)
    if e < p.rate_engage_q24:
        v_acc = _loop(v_prev, e, s.acc_e_prev_q24, p.rate_kp_q24, p.rate_ki_dt_q24, rate_owned)
        if v_acc < v:
            v, owner = v_acc, OWNER_ACCEL
    s.acc_e_prev_q24 = e
    e = sub_sat(p.n_limit_q24, n_q24)
    if e < p.n_limit_engage_q24:
        v_nl = _loop(
            v_prev,
            e,
            s.nlim_e_prev_q24,
            p.n_limit_kp_q24,
            p.n_limit_ki_dt_q24,
            s.owner == OWNER_NLIMIT,
        )
        if v_nl < v:
            v, owner = v_nl, OWNER_NLIMIT
    s.nlim_e_prev_q24 = e
    if p.fuel_schedules_on:
        # the line's fuel with the pump as estimated, within schedule_pump_range (the estimator
        # learns the pump while the line holds it: a weak pump's line rises)
        v_line = schedule_v(s, p, p.accel_line_q24, n_q24, p.sched_lam_lo_q24, p.sched_lam_hi_q24)
        if v_line < v:
            v, owner, by_line = v_line, OWNER_ACCEL, 1
    return v, owner, by_line


def decel_limits(
    s: EcuState, p: FirmwareParams, v_prev: int, v: int, owner: int, n_q24: int, rate_q24: int
) -> tuple[int, int]:
    """``v`` over the deceleration rate loop and the deceleration floor: (v, owner)."""
    e = add_sat(rate_q24, p.decel_max_q24)  # margin above the deceleration limit
    if e < p.rate_engage_q24:
        v_dec = _loop(
            v_prev, -e, -s.dec_e_prev_q24, p.rate_kp_q24, p.rate_ki_dt_q24, s.owner == OWNER_DECEL
        )
        if v_dec > v:
            v, owner = v_dec, OWNER_DECEL
    s.dec_e_prev_q24 = e
    if p.fuel_schedules_on:
        # one-sided: a weaker pump raises the floor, an estimate over Lambda_c never lowers it
        v_floor = schedule_v(s, p, p.decel_floor_q24, n_q24, p.sched_lam_lo_q24, p.lambda_comm_q24)
        if v_floor > v:
            v, owner = v_floor, OWNER_DECEL
    return v, owner


def reset_loops(s: EcuState, v_q24: int) -> None:
    """Start the limit loops from voltage v with no error history (entry into RUN)."""
    s.v_applied_q24 = v_q24
    s.line_owns = 0
    s.egt_e_prev_q24 = 0
    s.egt_vf_q24 = v_q24
    s.acc_e_prev_q24 = 0
    s.dec_e_prev_q24 = 0
    s.nlim_e_prev_q24 = 0
    s.owner = OWNER_SPEED
    s.v_saturated = 0
