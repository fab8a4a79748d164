"""ECU parameters: one structure in engineering units, its checks, and named presets.

``EcuParams`` is what a calibration engineer edits (floats, SI-ish units); ``validate`` refuses
malformed or unsafe values, naming the field. :mod:`ecu.firmware_params` compiles it into the
integer constants the firmware tick reads.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, fields, replace

N_MAX_RPM = 112_500  # 100 %N
RATE_MIN_HZ = 50
RATE_MAX_HZ = 1000
RATE_WINDOW_MAX_S = 0.05
RATE_BUF_LEN = RATE_MAX_HZ // 20 + 2  # central-difference ring: 0.05 s at 1000 Hz, +2 samples
LOG_ABORTS = 6  # the logbook's abort counters: one per start abort reason (ecu.logbook)

CONTROLLERS = ("mrac", "pid", "open_loop", "pi")
# how the document's printed gains are read (docs/errata.md, "Two readings"):
# "printed": f = [dN dV, dN^2 dV] and an absolute Lambda, as eq. 3.11 and 4.7 print them;
# "reproducing": f in the order of eq. 3.10, [dN^2 dV, dN dV], and Lambda a factor of
# B_p = [0, b0] (b0 = READING_B0), the reading that reproduces the published sec. 4.2 / 5.2 results
READINGS = ("printed", "reproducing")
# PlantSensors.EGT's full scale (protocol/turbojet.dbc): a thermocouple amplifier's upscale
# burnout reads it when the thermocouple is open
EGT_FULL_SCALE_K = 1638.3
CTRL_MRAC = 0
CTRL_PID = 1
CTRL_OPEN_LOOP = 2
CTRL_PI = 3
SCHED_POINTS = 12  # fuel schedule breakpoints: 45, 50, ..., 100 %N corrected
SCHED_N0_PCT = 45.0
SCHED_STEP_PCT = 5.0
T_STD_K = 288.15
INLET_RANGE_K = (223.0, 333.0)  # the day's inlet temperatures the ECU accepts
INLET_MIN_DK, INLET_MAX_DK = (round(t * 10.0) for t in INLET_RANGE_K)  # the same, 0.1 K
EGT_ERROR_MAX_DK = 1000  # the EGT loop's error is clamped to +- this, 0.1 K (and ecu_core.c)
EGT_ERROR_MAX_K = EGT_ERROR_MAX_DK / 10.0

# eq. 3.23: fast-model parameters identified offline on the aero-thermal model
AP_ROW2_EQ_3_23 = (-1.8054, -2.3360)
LAMBDA_EQ_3_23 = 4.8220
THETA_ROW2_EQ_3_23 = (-0.1835, -0.0001)
READING_B0 = LAMBDA_EQ_3_23  # B_p = [0, b0] of the reproducing reading


@dataclass(frozen=True)
class EcuParams:
    """All ECU parameters in engineering units (N in %N_max, V in volts, T in K, time in s)."""

    rate_hz: int = 100
    controller: str = "mrac"
    # how gamma_theta, init_theta_row2, gamma_f, init_kf and the Lambda and K gains are read
    # (READINGS); the firmware runs in the printed convention, see firmware_convention()
    reading: str = "printed"
    trim_n_pct: float = 89.68  # N0, the fast model's trim point
    # V0, pump voltage at trim: 12.41 V delivers the trim's 8 g/s against its P3 in our plant's
    # pump table (plant.aerothermal: trim_pump_voltage); the fast model is in deviations from it
    trim_v: float = 12.41
    # pump voltage on entry into RUN, the limit loops and the PI(D)'s integrator started from it
    # (bumpless): the trim voltage, or what a run that starts elsewhere held before it began
    entry_v: float = 12.41

    # online estimator (eq. 4.7, 4.31); row 1 of A_p and Theta_f is kinematic and not adapted
    am_row2: tuple[float, float] = (-25.0, -10.0)  # identification model A_m row 2
    p22: float = 1.0  # P[1][1]; P[0][0] only weighs the row-1 error, which is not adapted
    # P[0][1]: weighs the speed error e1 into the row-2 laws, (P e)_2 = p12 e1 + p22 e2. The
    # document's diagonal P (p12 = 0) sees a parameter error only through e2 = s/(s^2 - am22 s
    # - am21) of it, which is blind to steady state; a P solving A_m^T P + P A_m = -Q (Q >= 0)
    # has 0 <= p12 <= -am22 p22 and gives the laws the steady-state error too
    p12: float = 5.0
    # practical defaults: only the pump's effectiveness adapts (Lambda-hat, with Theta_f-hat in
    # proportion: pump_scaling_on); the engine's dynamics (A_p) stay as commissioned. On the
    # aero-thermal engine, whose fast second pole the fast model lacks, an adapted A_p drifts
    # along the directions the steps do not excite and takes Lambda-hat with it
    gamma_a: tuple[float, float] = (0.0, 0.0)
    gamma_lambda: float = 0.05  # its regressor is the absolute voltage, about 10 V
    gamma_theta: tuple[float, float] = (0.01, 0.001)  # used with pump_scaling_on off
    init_ap_row2: tuple[float, float] = AP_ROW2_EQ_3_23
    init_lambda: float = LAMBDA_EQ_3_23
    init_theta_row2: tuple[float, float] = THETA_ROW2_EQ_3_23
    lambda_commissioned: float = LAMBDA_EQ_3_23  # reference for pump health
    pump_health_alarm: float = 0.70  # alarm below this fraction of the commissioned Lambda
    rate_window_s: float = 0.04  # central difference of speed over +-window/2
    # robustness (each can be switched off to reproduce the document exactly)
    lambda_floor_on: bool = True
    lambda_floor: float = 1.0
    dead_zone_on: bool = True
    speed_noise_rpm: float = 3.0  # speed sensor noise (1 sigma); sizes the dead zone
    dead_zone_sigmas: float = 3.0
    # no adaptation while V saturates or a limit loop owns the command; while the acceleration
    # line holds it the estimator learns on from the voltage applied (the pump the line holds)
    freeze_on: bool = True
    # no adaptation further than this from the trim speed (0: everywhere), where the fast model,
    # linearised at trim, no longer holds: at 55 %N Lambda-hat would fall to a quarter of
    # Lambda_c within a second, carrying the model's error rather than the pump's
    adapt_band_pct: float = 25.0
    # the pump's effectiveness scales the whole fuel path: fuel goes with Lambda-hat times the
    # absolute pump voltage, so a changed Lambda-hat moves the trim voltage (a bias
    # (Lambda-hat - lambda_commissioned) (trim_v - pump_dead_v) in eq. 4.7, cancelled by the
    # MRAC's K_b) and
    # Theta_f-hat in proportion (not adapted on its own); off: eq. 4.7 as printed
    pump_scaling_on: bool = True
    # the pump delivers nothing below this voltage (leakage against its outlet pressure): fuel
    # goes with Lambda-hat (V - pump_dead_v); our plant's pump: about 1.8 V near trim pressure
    pump_dead_v: float = 1.8

    # indirect MRAC (eq. 5.4, 5.15-5.16, 5.18-5.19)
    ref_wn: float = 5.0
    ref_zeta: float = 1.0
    gamma_x: tuple[float, float] = (0.1, 0.1)
    gamma_r: float = 0.1
    gamma_f: tuple[float, float] = (0.1, 0.1)
    gamma_b: float = 0.1  # K_b, the bias gain (pump_scaling_on), by the law of eq. 5.16
    init_kx: tuple[float, float] = (-4.809, -1.589)
    init_kr: float = 5.185
    init_kf: tuple[float, float] = (0.03805, 0.00002)
    u_den_min: float = 0.5  # floor of (1 - K_f g(dN)) when solving eq. 5.4 for u
    # the MRAC's command through a first-order lag of this time constant (0: none). The fast
    # model (eq. 3.24) puts the pump in the shaft's acceleration; our engine's shaft answers the
    # pump at once, its rate K / tau_shaft = 2.7 %N/s per V above the shaft's pole at 90 %N. A lag
    # of K / tau_shaft / Lambda makes lag and engine the model the MRAC is designed on, with its
    # high-frequency gain Lambda (`sil bench control`: matching_lag_s); without it the rate gain
    # K_x2 meets a flat loop gain of about 4 and limit-cycles on the pump's slew
    mrac_cmd_lag_s: float = 0.55

    # PID baseline (chapter 6)
    pid_kp: float = 2.0
    pid_ki: float = 1.0
    pid_kd: float = 0.5

    # gain-scheduled PI baseline (ecu.pi_design): designed from the commissioned fast model
    # (init_ap_row2, init_lambda, init_theta_row2) for this crossover and phase margin
    pi_bandwidth: float = 1.75  # rad/s
    pi_phase_margin: float = 50.0  # degrees, at least 50

    # demand
    idle_pct: float = 35.0
    demand_max_pct: float = 100.0

    # protection; EGT defaults from our plant's running line (sil steady-line): a healthy engine
    # runs 1048 K at 89.68 %N and about 1255 K at 100 %N, hotter than the Olympus spec's 973 K
    # (see the design brief); the limit sits 25 K above that, the shutdown 75 K above
    limiters_on: bool = True
    egt_limit_k: float = 1280.0
    egt_kp: float = 0.01  # V per K
    egt_ki: float = 0.02  # V per K s
    egt_engage_k: float = 50.0  # the EGT loop joins the min-select within this of its limit
    # the EGT loop sees the gas, not the probe: lead (T_tc s + 1)/(T_f s + 1) against the
    # thermocouple's lag, T_tc its commissioned time constant (0 with T_f 0: the raw reading)
    egt_lead_tau_s: float = 0.5
    egt_lead_filter_s: float = 0.1  # T_f: gain on probe noise (T_tc + dt)/(T_f + dt), 4.6
    # a transient allowance: the gas the lead sees may pass the limit by what the probe still
    # reads under it, up to this much (0: the gas is held at the limit)
    egt_gas_margin_k: float = 0.0
    # the EGT-limited acceleration line of this engine (with fuel_schedules_on): at frozen speed
    # the gas rises linearly with the pump's fuel, from T_0 at none, so the voltage that puts it
    # at the limit is V_d + (V_f - V_d) (T_lim - T_0) / (T_gas - T_0), V_f the applied voltage
    # through the gas estimate's own lag; `sil schedules`: T_0 291-367 K over the +-5 % health
    # corners and 45-100 %N, the lowest the safe one (a lower T_0, a lower line); 0: off
    egt_zero_fuel_k: float = 290.0
    egt_max_k: float = 1330.0  # shutdown above this ...
    egt_max_time_s: float = 1.0  # ... for this long
    accel_max_pct_s: float = 20.0
    decel_max_pct_s: float = 30.0
    rate_kp: float = 0.5  # V per (%N/s)
    rate_ki: float = 2.0  # V per (%N/s) s
    rate_engage_pct_s: float = 5.0
    n_limit_pct: float = 102.0  # topping governor (min-select)
    n_limit_kp: float = 0.5
    n_limit_ki: float = 5.0
    n_limit_engage_pct: float = 2.0
    overspeed_pct: float = 105.0
    overspeed_time_s: float = 0.5
    flameout_margin: float = 0.10  # fraction under idle
    flameout_time_s: float = 3.0
    # or, faster, the EGT under this (a lit engine runs 650 K at idle on a 253 K day and dips
    # to about 520 K in a throttle chop; its flame out, the gas cools under 420 K within 1-2 s)
    flameout_egt_k: float = 420.0
    flameout_egt_time_s: float = 0.3
    v_min: float = 1.0
    v_max: float = 20.0  # within 95 % duty of a sagging 6S pack (22.2 V nominal)
    # the fastest the pump command may move: at 20 V/s the gas of a hot engine with a strong pump
    # overshoots its limit by up to 86 K within 0.15 s of a step, before the EGT loop's probe can
    # show it; at 12 V/s its EGT loop holds it (engine-variation campaign)
    v_slew_v_s: float = 12.0
    # fuel schedules against corrected speed N / sqrt(inlet_temp_k / 288.15), at SCHED_N0_PCT +
    # k SCHED_STEP_PCT, as the pump voltage of a commissioned pump (`sil schedules` on our plant:
    # EGT 1280 K, surge margin 10 %, lean blow-out margin 30 %, for every engine within +-5 %
    # health); with pump_scaling_on the ECU
    # moves them with its pump: V_d + (V - V_d) Lambda_c / Lambda-hat, the same fuel, Lambda-hat
    # taken within schedule_pump_range of Lambda_c (an estimate in a transient must not raise the
    # floor into an over-temperature). Within the limit loops (limiters_on): the acceleration
    # line caps the pump voltage from the first tick, the floor holds it up against every other
    fuel_schedules_on: bool = True
    # (0.7, 1.0): the line rises for a weaker pump and never falls for a stronger one, whose
    # extra fuel the EGT line, the EGT loop and the rate loop hold; off trim Lambda-hat reads a
    # nominal pump 2-3 % strong (the fast model's bias), which with a range over 1 put the line
    # under the steady line near 100 %N and held the engine short of it at maximum demand
    schedule_pump_range: tuple[float, float] = (0.7, 1.0)
    accel_line_v: tuple[float, ...] = (
        5.34, 6.91, 7.96, 8.9, 9.88, 10.88, 11.91, 12.96, 14.03, 15.28, 16.41, 17.96,
    )  # fmt: skip
    decel_floor_v: tuple[float, ...] = (
        2.83, 3.06, 3.3, 3.55, 3.82, 4.1, 4.39, 4.69, 5.0, 5.32, 5.65, 5.99,
    )  # fmt: skip
    # the acceleration schedule (Ndot limit), %N/s against the same corrected speeds: the rate
    # loop holds the shaft's acceleration under it (and under accel_max_pct_s); `sil schedules`:
    # 1.2 times the nominal engine's rate on the line, at least 5 %N/s
    accel_rate_pct_s: tuple[float, ...] = (
        5.0, 7.9, 10.1, 11.7, 12.9, 13.3, 13.7, 13.2, 11.6, 9.3, 5.1, 5.0,
    )  # fmt: skip
    # no inlet sensor: the day's temperature, set by the operator; with inlet_from_egt a start
    # from rest takes the EGT read before it (a cold engine's thermocouple reads the air) when
    # it lies in INLET_RANGE_K (ecu.inlet)
    inlet_temp_k: float = 288.15
    inlet_from_egt: bool = True

    # pump driver
    duty_min: float = 0.0
    duty_max: float = 0.95
    supply_nominal_v: float = 22.2  # 6S pack; used while the analog frame is lost
    # pump current (our plant's pump: 0.25 A + 0.06 A/V friction, + 4 uA/Pa against pressure):
    # stalled = seized (current high) or tripped by the driver (current near zero) with voltage
    # applied; dry = only the friction current (under dry_base + dry_per_v * V)
    pump_stall_ma: float = 5000.0
    pump_trip_ma: float = 100.0
    pump_stall_time_s: float = 0.3
    pump_dry_base_ma: float = 500.0
    pump_dry_ma_per_v: float = 60.0
    pump_dry_min_v: float = 2.0
    pump_dry_time_s: float = 0.5

    # fault detection
    speed_valid_max_rpm: float = 140_000.0
    speed_rate_max_pct_s: float = 200.0
    speed_fault_time_s: float = 0.05
    speed_stuck_time_s: float = 0.5
    speed_stuck_dv: float = 0.5
    egt_open_high_k: float = 1600.0  # under the EGT signal's full scale (an open circuit reads it)
    egt_open_low_k: float = 200.0
    egt_fault_time_s: float = 0.1
    egt_fail_demand_max_pct: float = 90.0
    observer_l: tuple[float, float] = (18.0, 57.0)
    # the speed rate the control laws and limit loops use: the central difference over
    # rate_window_s, as the document differentiates, or (on) a tracking filter on the measured
    # speed told the pump's input (ecu.rate_filter), triple pole at rate_filter_bw. The filter
    # keeps the speed noise off the pump; the PID gains from it in tracking too, but the MRAC's
    # rate gain K_x2 loses margin to it on engines unlike the commissioned one (off by default).
    # The estimator always takes central differences (its interval is delayed anyway)
    rate_filter_on: bool = False
    rate_filter_bw: float = 8.0  # rad/s

    # communication timeouts
    demand_hold_s: float = 0.1
    demand_shutdown_s: float = 2.0
    sensor_loss_s: float = 0.2
    analog_loss_s: float = 0.15  # analog frames come every 50 ms: three missed ones
    run_entry_pct: float = 31.5  # ARMED -> RUN once the starter has the engine this fast
    shutdown_done_pct: float = 10.0  # SHUTDOWN -> OFF below this

    # start and stop sequencer (ecu.start_sequencer); with start_on, ARMED starts the engine
    # from rest (else it waits for an external starter to bring it to run_entry_pct). Defaults
    # for our plant: ignition at 8 %N (9,000 rpm), where a few tenths of g/s of fuel burn
    # under stoichiometric (at 4 %N a strong pump's light-off is rich and hot); starter cut-off
    # at 51 %N, over the speed where the engine makes more power than it absorbs within the
    # start's EGT target (about 30 %N corrected for the nominal engine, but about 50 %N for the
    # weakest of a +-5 % health variation on a hot day: cut at 36 %N they hang); hand-over to
    # the speed control at 52 %N, over the lowest speed every engine of that variation holds by
    # itself at 288 K (46 %N; the nominal 38 %N)
    start_on: bool = True
    start_duty: float = 0.5  # starter duty while spinning up and igniting
    start_purge_s: float = 2.5  # the least spin-up time: the air purges, the glow plug heats
    start_ignition_pct: float = 8.0  # fuel on from this speed
    start_spinup_timeout_s: float = 10.0  # STARTER_FAILURE if not at the ignition speed by then
    start_ign_v0: float = 1.7  # pump voltage at fuel-on (just over the pump's dead band)
    start_ign_v_rate: float = 0.1  # V/s, the ignition fuel ramp
    start_ign_v_max: float = 2.5
    start_light_rise_k: float = 30.0  # light-off: the EGT this much over a reference which ...
    start_light_track_k_s: float = 20.0  # ... follows a slower rise (not a flame's)
    start_ignition_timeout_s: float = 15.0  # IGNITION_TIMEOUT after this long with fuel on
    start_igniter_hold_s: float = 1.0  # the igniter stays on this long after light-off
    start_starter_ramp_s: float = 3.0  # starter from start_duty to full after light-off
    start_ramp_v_rate: float = 0.2  # V/s, the fuel ramp of the lit engine, up while ...
    start_accel_pct_s: float = 4.0  # ... it accelerates slower than this, down ...
    start_egt_target_k: float = 1180.0  # ... over this EGT on a 288.15 K day (times theta on ...
    start_egt_limit_k: float = 1250.0  # HOT_START over this during the start
    start_egt_margin_k: float = 20.0  # ... the day, kept this far under the HOT_START limit)
    start_cutoff_pct: float = 51.0  # starter off
    start_ramp_timeout_s: float = 25.0  # SLOW_ACCEL: light-off to cut-off
    start_idle_pct: float = 52.0  # the start hands over to the speed control (RUN) here
    start_stabilise_timeout_s: float = 15.0  # SLOW_ACCEL: cut-off to idle
    relight_max: int = 1  # relight attempts after a flameout in RUN (0: shut down at once)
    cool_duty: float = 0.6  # starter duty while cooling after a shutdown
    cool_egt_k: float = 363.0  # cooled below this EGT
    cool_rearm_k: float = 10.0  # cool again if the EGT soaks back this far over cool_egt_k ...
    cool_soak_s: float = 15.0  # ... within this long after the cooling stopped (then: cooled)
    cool_speed_pct: float = 40.0  # the starter engages below this speed
    cool_timeout_s: float = 120.0


def _doc_common(**kw: object) -> EcuParams:
    """Document reproduction: limiters, fuel schedules and robustness off, rate over +-1 tick
    at 100 Hz."""
    base = EcuParams(
        lambda_floor_on=False,
        dead_zone_on=False,
        freeze_on=False,
        adapt_band_pct=0.0,
        pump_scaling_on=False,
        p12=0.0,
        limiters_on=False,
        rate_window_s=0.02,
        fuel_schedules_on=False,
        mrac_cmd_lag_s=0.0,
    )
    return replace(base, **kw)  # type: ignore[arg-type]


PRESETS: dict[str, EcuParams] = {
    # practical default: MRAC from the commissioned eq. 3.23 model, robustness and limiters on
    "default": EcuParams(),
    # sec. 4.2: estimator alone, open-loop square wave on pump voltage (eq. 4.34-4.41)
    "sec4_2_estimator": _doc_common(
        controller="open_loop",
        am_row2=(-0.36, -1.2),
        p22=1.0,
        gamma_a=(20.0, 20.0),
        gamma_lambda=3.0,
        gamma_theta=(0.01, 100.0),
        init_ap_row2=(-1.0, -2.0),
        init_lambda=0.5,
        init_theta_row2=(0.0, 0.0),
    ),
    # sec. 5.2: indirect MRAC on the fast model (eq. 5.18-5.32)
    "sec5_2_mrac_fast": _doc_common(
        controller="mrac",
        am_row2=(-25.0, -10.0),
        gamma_a=(3.0, 3.0),
        gamma_lambda=0.017,
        gamma_theta=(0.004, 8.0),
        init_ap_row2=(-0.5, -1.0),
        init_lambda=4.3,
        init_theta_row2=(0.0, 0.0),
        gamma_x=(0.1, 0.1),
        gamma_r=0.1,
        gamma_f=(0.1, 0.1),
        init_kx=(0.0, 0.0),
        init_kr=0.0,
        init_kf=(0.0, 0.0),
    ),
}


# sec. 5.3: the sec. 5.2 set-up on the aero-thermal model, with its own learning rates
PRESETS["sec5_3_mrac_aero"] = replace(
    PRESETS["sec5_2_mrac_fast"], gamma_lambda=0.015, gamma_theta=(0.02, 0.1)
)
# the same set-ups in the reading that reproduces the published results (READINGS)
PRESETS["sec4_2_estimator_reproducing"] = replace(
    PRESETS["sec4_2_estimator"], reading="reproducing"
)
PRESETS["sec5_2_mrac_fast_reproducing"] = replace(
    PRESETS["sec5_2_mrac_fast"], reading="reproducing"
)


def firmware_convention(p: EcuParams) -> EcuParams:
    """``p`` in the convention the firmware and its twins run: f = [dN dV, dN^2 dV], Lambda
    absolute. The reproducing reading maps onto it exactly:

    - eq. 3.10 order: Theta_f and K_f pair with [dN^2 dV, dN dV], so their gains and initial
      values are the printed convention's reversed;
    - Lambda = b0 lambda with lambda adapted against B_p = [0, b0]: lambda' = -Gamma b0 e u is
      Lambda' = -(Gamma b0^2) e u, and the K laws' B_p^T (A_p + B_p lambda K - A_m) = b0 (A_p +
      Lambda K - A_m) scale Gamma_x, Gamma_r, Gamma_f (and Gamma_b) by b0. Initial and reported
      Lambda are b0 lambda, as printed.
    """
    if p.reading == "printed":
        return p
    b0 = READING_B0
    return replace(
        p,
        reading="printed",
        gamma_theta=p.gamma_theta[::-1],
        init_theta_row2=p.init_theta_row2[::-1],
        gamma_lambda=p.gamma_lambda * b0 * b0,
        gamma_x=(p.gamma_x[0] * b0, p.gamma_x[1] * b0),
        gamma_r=p.gamma_r * b0,
        gamma_f=(p.gamma_f[1] * b0, p.gamma_f[0] * b0),
        gamma_b=p.gamma_b * b0,
        init_kf=p.init_kf[::-1],
    )


def preset(name: str, **overrides: object) -> EcuParams:
    """A named preset, optionally with fields replaced."""
    if name not in PRESETS:
        raise ValueError(f"unknown ECU preset {name!r}; choose from {sorted(PRESETS)}")
    return replace(PRESETS[name], **overrides)  # type: ignore[arg-type]


class ParamError(ValueError):
    """A parameter is missing, malformed or unsafe; the message names the field."""


def _check(cond: bool, field: str, value: object, why: str) -> None:
    if not cond:
        raise ParamError(f"{field}={value!r}: {why}")


def _check_sequencer(p: EcuParams) -> None:
    """The start and stop sequencer's parameters: duties in (0, 1], speeds and temperatures in
    the order the sequence passes them, positive times."""
    for name in ("start_duty", "cool_duty"):
        _check(0.0 < getattr(p, name) <= 1.0, name, getattr(p, name), "must be in (0, 1]")
    _check(
        0.5 <= p.start_ignition_pct < p.start_cutoff_pct < p.start_idle_pct <= 60.0,
        "start_cutoff_pct",
        p.start_cutoff_pct,
        "need 0.5 <= start_ignition_pct < start_cutoff_pct < start_idle_pct <= 60",
    )
    _check(
        p.start_idle_pct >= p.idle_pct * (1.0 - p.flameout_margin),
        "start_idle_pct",
        p.start_idle_pct,
        "must not be below the flameout threshold",
    )
    _check(
        0.0 < p.start_ign_v0 < p.start_ign_v_max <= p.v_max,
        "start_ign_v_max",
        p.start_ign_v_max,
        "need 0 < start_ign_v0 < start_ign_v_max <= v_max",
    )
    _check(
        400.0 <= p.start_egt_target_k < p.start_egt_limit_k <= p.egt_max_k,
        "start_egt_limit_k",
        p.start_egt_limit_k,
        "need 400 K <= start_egt_target_k < start_egt_limit_k <= egt_max_k",
    )
    _check(
        0.0 <= p.start_egt_margin_k <= p.start_egt_limit_k - 400.0,
        "start_egt_margin_k",
        p.start_egt_margin_k,
        "need 0 <= start_egt_margin_k <= start_egt_limit_k - 400 K",
    )
    _check(5.0 <= p.start_light_rise_k <= 300.0, "start_light_rise_k", p.start_light_rise_k,
           "must be in 5-300 K")  # fmt: skip
    _check(1.0 <= p.start_light_track_k_s <= 200.0, "start_light_track_k_s",
           p.start_light_track_k_s, "must be in 1-200 K/s")  # fmt: skip
    _check(300.0 <= p.cool_egt_k <= 500.0, "cool_egt_k", p.cool_egt_k, "must be in 300-500 K")
    _check(1.0 <= p.cool_rearm_k <= 200.0, "cool_rearm_k", p.cool_rearm_k, "must be in 1-200 K")
    _check(5.0 <= p.cool_speed_pct <= 60.0, "cool_speed_pct", p.cool_speed_pct, "must be in 5-60")
    _check(isinstance(p.relight_max, int) and 0 <= p.relight_max <= 5, "relight_max",
           p.relight_max, "must be an integer in 0..5")  # fmt: skip
    _check(0.2 <= p.start_accel_pct_s <= 20.0, "start_accel_pct_s", p.start_accel_pct_s,
           "must be in 0.2-20 %N/s")  # fmt: skip
    for name in ("start_ign_v_rate", "start_ramp_v_rate"):
        _check(0.0 < getattr(p, name) <= 5.0, name, getattr(p, name), "must be in (0, 5] V/s")
    for name in (
        "start_purge_s",
        "start_spinup_timeout_s",
        "start_ignition_timeout_s",
        "start_igniter_hold_s",
        "start_starter_ramp_s",
        "start_ramp_timeout_s",
        "start_stabilise_timeout_s",
        "cool_timeout_s",
        "cool_soak_s",
    ):
        _check(0.0 < getattr(p, name) <= 300.0, name, getattr(p, name), "must be in (0, 300] s")
    _check(p.start_purge_s < p.start_spinup_timeout_s, "start_spinup_timeout_s",
           p.start_spinup_timeout_s, "must exceed start_purge_s")  # fmt: skip


def validate(p: EcuParams) -> None:
    """Refuse malformed or unsafe parameters, naming the field."""
    for f in fields(p):
        v = getattr(p, f.name)
        vals = v if isinstance(v, tuple) else (v,)
        for x in vals:
            if isinstance(x, float) and not math.isfinite(x):
                raise ParamError(f"{f.name}={v!r}: not finite")
        if f.name.endswith("_on") and v not in (0, 1):  # a switch: on or off, nothing else
            raise ParamError(f"{f.name}={v!r}: a switch is true or false (1 or 0)")
    _check(
        isinstance(p.rate_hz, int) and RATE_MIN_HZ <= p.rate_hz <= RATE_MAX_HZ,
        "rate_hz",
        p.rate_hz,
        f"must be an integer in {RATE_MIN_HZ}..{RATE_MAX_HZ}",
    )
    _check(p.controller in CONTROLLERS, "controller", p.controller, f"one of {CONTROLLERS}")
    _check(p.reading in READINGS, "reading", p.reading, f"one of {READINGS}")
    _check(0.0 < p.trim_n_pct < 110.0, "trim_n_pct", p.trim_n_pct, "must be in (0, 110)")
    _check(p.v_min <= p.trim_v <= p.v_max, "trim_v", p.trim_v, "must lie in [v_min, v_max]")
    band = p.adapt_band_pct
    _check(0.0 <= band <= 60.0, "adapt_band_pct", band, "must be in [0, 60]")
    _check(p.v_min <= p.entry_v <= p.v_max, "entry_v", p.entry_v, "must lie in [v_min, v_max]")
    a21, a22 = p.am_row2
    _check(a21 < 0.0 and a22 < 0.0, "am_row2", p.am_row2, "A_m must be Hurwitz (both < 0)")
    _check(p.p22 > 0.0, "p22", p.p22, "P must be positive definite")
    _check(
        0.0 <= p.p12 <= -a22 * p.p22,
        "p12",
        p.p12,
        f"a Lyapunov P of A_m has 0 <= p12 <= -am22 * p22 = {-a22 * p.p22:g}",
    )
    dt = 1.0 / p.rate_hz
    for name in ("gamma_a", "gamma_theta", "gamma_x", "gamma_f"):
        for g in getattr(p, name):
            _check(g >= 0.0, name, getattr(p, name), "learning rates must be >= 0")
            _check(g * p.p22 * dt < 4.0, name, getattr(p, name), "gain * P * dt must be < 4")
    for name in ("gamma_lambda", "gamma_r", "gamma_b"):
        g = getattr(p, name)
        _check(g >= 0.0, name, g, "learning rates must be >= 0")
        _check(g * p.p22 * dt < 4.0, name, g, "gain * P * dt must be < 4")
    _check(p.init_lambda > 0.0, "init_lambda", p.init_lambda, "pump gain must be > 0")
    _check(p.lambda_commissioned > 0.0, "lambda_commissioned", p.lambda_commissioned, "> 0")
    _check(0.0 < p.pump_health_alarm < 1.0, "pump_health_alarm", p.pump_health_alarm, "in (0,1)")
    _check(p.lambda_floor > 0.0, "lambda_floor", p.lambda_floor, "must be > 0")
    _check(0.0 <= p.pump_dead_v < p.trim_v, "pump_dead_v", p.pump_dead_v, "need 0 <= x < trim_v")
    _check(
        2.0 / p.rate_hz <= p.rate_window_s <= RATE_WINDOW_MAX_S,
        "rate_window_s",
        p.rate_window_s,
        f"must span at least two ticks and at most {RATE_WINDOW_MAX_S} s",
    )
    _check(p.speed_noise_rpm >= 0.0, "speed_noise_rpm", p.speed_noise_rpm, "must be >= 0")
    _check(p.ref_wn > 0.0 and p.ref_zeta > 0.0, "ref_wn", (p.ref_wn, p.ref_zeta), "must be > 0")
    _check(0.05 <= p.u_den_min <= 1.0, "u_den_min", p.u_den_min, "must be in [0.05, 1]")
    _check(0.0 <= p.mrac_cmd_lag_s <= 5.0, "mrac_cmd_lag_s", p.mrac_cmd_lag_s, "must be in 0-5 s")
    for name in ("pid_kp", "pid_ki", "pid_kd", "egt_kp", "egt_ki", "rate_kp", "rate_ki"):
        _check(getattr(p, name) >= 0.0, name, getattr(p, name), "must be >= 0")
    _check(0.0 < p.idle_pct < p.demand_max_pct, "idle_pct", p.idle_pct, "0 < idle < max demand")
    _check(p.demand_max_pct <= 105.0, "demand_max_pct", p.demand_max_pct, "must be <= 105")
    _check(
        p.demand_max_pct < p.n_limit_pct < p.overspeed_pct <= 110.0,
        "n_limit_pct",
        p.n_limit_pct,
        "need demand_max_pct < n_limit_pct < overspeed_pct <= 110",
    )
    _check(800.0 <= p.egt_limit_k < p.egt_max_k, "egt_limit_k", p.egt_limit_k, "800 <= x < max")
    _check(
        0.0 <= p.egt_gas_margin_k <= p.egt_max_k - p.egt_limit_k,
        "egt_gas_margin_k",
        p.egt_gas_margin_k,
        "need 0 <= x <= egt_max_k - egt_limit_k (the gas stays under the shutdown level)",
    )
    _check(
        p.egt_zero_fuel_k == 0.0 or 150.0 <= p.egt_zero_fuel_k <= p.egt_limit_k - 300.0,
        "egt_zero_fuel_k",
        p.egt_zero_fuel_k,
        "need 0 (off) or 150 K <= x <= egt_limit_k - 300 K",
    )
    _check(p.egt_max_k < p.egt_open_high_k, "egt_max_k", p.egt_max_k, "below open-circuit level")
    _check(
        p.egt_open_high_k < EGT_FULL_SCALE_K,
        "egt_open_high_k",
        p.egt_open_high_k,
        f"below the EGT signal's full scale {EGT_FULL_SCALE_K} K, where an open circuit reads",
    )
    for name in ("egt_lead_tau_s", "egt_lead_filter_s"):
        _check(0.0 <= getattr(p, name) <= 5.0, name, getattr(p, name), "must be in [0, 5] s")
    _check(
        p.egt_lead_tau_s <= 20.0 * p.egt_lead_filter_s,
        "egt_lead_filter_s",
        p.egt_lead_filter_s,
        "at least egt_lead_tau_s / 20 (the lead's gain on sensor noise stays under 20)",
    )
    _check(p.accel_max_pct_s > 0.0, "accel_max_pct_s", p.accel_max_pct_s, "must be > 0")
    _check(p.decel_max_pct_s > 0.0, "decel_max_pct_s", p.decel_max_pct_s, "must be > 0")
    for name in ("egt_engage_k", "rate_engage_pct_s", "n_limit_engage_pct"):
        _check(getattr(p, name) > 0.0, name, getattr(p, name), "must be > 0")
    _check(
        p.egt_engage_k <= EGT_ERROR_MAX_K,
        "egt_engage_k",
        p.egt_engage_k,
        f"at most {EGT_ERROR_MAX_K:g} K, the EGT loop's error clamp (over it the loop never leaves"
        " the min-select, and its integral caps every acceleration far from the limit)",
    )
    _check(0.0 <= p.v_min < p.v_max <= 30.0, "v_max", p.v_max, "need 0 <= v_min < v_max <= 30")
    _check(p.v_slew_v_s > 0.0, "v_slew_v_s", p.v_slew_v_s, "must be > 0")
    _check(0.0 <= p.duty_min < p.duty_max <= 1.0, "duty_max", p.duty_max, "0 <= min < max <= 1")
    _check(p.supply_nominal_v > p.v_min, "supply_nominal_v", p.supply_nominal_v, "> v_min")
    _check(
        0.0 <= p.pump_trip_ma < p.pump_dry_base_ma < p.pump_stall_ma,
        "pump_dry_base_ma",
        p.pump_dry_base_ma,
        "need pump_trip_ma < pump_dry_base_ma < pump_stall_ma",
    )
    _check(p.pump_dry_ma_per_v >= 0.0, "pump_dry_ma_per_v", p.pump_dry_ma_per_v, "must be >= 0")
    _check(0.0 < p.flameout_margin < 0.5, "flameout_margin", p.flameout_margin, "in (0, 0.5)")
    _check(
        p.run_entry_pct >= p.idle_pct * (1.0 - p.flameout_margin),
        "run_entry_pct",
        p.run_entry_pct,
        "must not be below the flameout threshold",
    )
    _check(0.0 < p.demand_hold_s < p.demand_shutdown_s, "demand_hold_s", p.demand_hold_s, "< 2 s")
    _check_sequencer(p)
    for name in (
        "egt_max_time_s",
        "overspeed_time_s",
        "flameout_time_s",
        "flameout_egt_time_s",
        "pump_stall_time_s",
        "pump_dry_time_s",
        "speed_fault_time_s",
        "speed_stuck_time_s",
        "egt_fault_time_s",
        "sensor_loss_s",
        "analog_loss_s",
        "demand_shutdown_s",
    ):
        _check(getattr(p, name) > 0.0, name, getattr(p, name), "must be > 0")
    _check(min(p.observer_l) >= 0.0, "observer_l", p.observer_l, "must be >= 0")
    for name in ("accel_line_v", "decel_floor_v"):
        table = getattr(p, name)
        _check(len(table) == SCHED_POINTS, name, table, f"needs {SCHED_POINTS} values")
        _check(all(0.0 <= v <= 30.0 for v in table), name, table, "every value in 0-30 V")
        _check(all(b >= a for a, b in itertools.pairwise(table)), name, table, "must not fall")
    table = p.accel_rate_pct_s
    _check(len(table) == SCHED_POINTS, "accel_rate_pct_s", table, f"needs {SCHED_POINTS} values")
    _check(all(0.5 <= r <= 100.0 for r in table), "accel_rate_pct_s", table,
           "every value in 0.5-100 %N/s")  # fmt: skip
    _check(
        all(d < a for d, a in zip(p.decel_floor_v, p.accel_line_v, strict=True)),
        "decel_floor_v",
        p.decel_floor_v,
        "must lie under accel_line_v at every speed",
    )
    lo, hi = p.schedule_pump_range
    _check(0.3 <= lo <= 1.0 <= hi <= 3.0, "schedule_pump_range", p.schedule_pump_range,
           "needs 0.3 <= low <= 1 <= high <= 3")  # fmt: skip
    lo, hi = INLET_RANGE_K
    _check(lo <= p.inlet_temp_k <= hi, "inlet_temp_k", p.inlet_temp_k, "must be in 223-333 K")
    _check(
        0.2 <= p.pi_bandwidth <= 10.0, "pi_bandwidth", p.pi_bandwidth, "must be in [0.2, 10] rad/s"
    )
    _check(
        50.0 <= p.pi_phase_margin <= 80.0,
        "pi_phase_margin",
        p.pi_phase_margin,
        "must be in [50, 80] degrees",
    )
    # bw dt <= 0.3: a discrete filter well inside its rate, and its gains inside Q7.24
    _check(
        2.0 <= p.rate_filter_bw <= min(50.0, 0.3 * p.rate_hz),
        "rate_filter_bw",
        p.rate_filter_bw,
        "must be in [2, min(50, 0.3 rate_hz)] rad/s",
    )
