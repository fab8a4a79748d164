/*
 * ecu_core.h - turbojet ECU control core, C99 port of the Python firmware (ecu/firmware.py).
 *
 * Bit-exact with the Python tick: same Q formats (names end in _q24 = Q7.24, _q16 = Q15.16,
 * _q28 = Q3.28), 64-bit intermediates, truncation by arithmetic shift, C division, saturating
 * stores with the saturation events counted, and the same state layout field by field. Golden
 * vectors written by the Python firmware (ecu/golden.py) prove it, every integer of every tick.
 *
 * Integration (your scheduler, your CAN driver):
 *
 *     static ecu_params_t params;    // or a const one in flash: python -m ecu.port.export
 *     static ecu_t ecu;              // all state: no heap, no globals in the core
 *
 *     ecu_params_load(&params, words, ECU_PARAM_WORDS);   // once: calibration words (below)
 *     ecu_init(&ecu, &params);                             // power-on: mode OFF
 *     every period (100 Hz by default; params.rate_hz):
 *         fill an ecu_inputs_t from the frames received since the last tick (raw integers in
 *         the CAN contract's units; one E2E status per frame kind, see ECU_E2E_*),
 *         const ecu_outputs_t *o = ecu_tick(&ecu, &in);
 *         send o->duty_cpct / o->pump_enable to the pump driver, o->starter_cpct and
 *         o->igniter to the starter and the igniter (the start/stop sequencer drives them in
 *         ECU_ARMED and ECU_SHUTDOWN), and the ECU frames (ecu_frames.h packs them from the
 *         outputs, with E2E CRC and alive counter).
 *
 * ecu_tick is reentrant per instance, runs in bounded time, uses no floating point and calls
 * no library function: its 64-bit divisions are its own, in 32-bit divisions (UDIV on a
 * Cortex-M4). Its loops are the integer square root of the inlet correction, at most 32
 * passes and only in the tick that starts the engine from rest, and a division's digit
 * correction, at most twice per digit; everything else is straight-line code. Inputs are
 * expected in the ranges their DBC signals can carry (speed 0..262143 rpm, EGT 0..16383 dK,
 * supply and current 0..65535, demand 0..65535); within them no intermediate overflows 64 bits.
 *
 * Parameters are the integer constants that ecu.firmware_params.compile_params computes from the
 * engineering-unit calibration (the one place where floats become Q formats); they are loaded
 * as ECU_PARAM_WORDS int32 words in the order of ECU_PARAM_FIELDS.
 *
 * Requires: int32_t/int64_t (exact-width, so two's complement without padding bits), an int
 * of at least 32 bits and arithmetic right shift of negative values (gcc, clang, armcc, IAR on
 * every 32-bit MCU); ecu_core.c checks them at compile time, with the records' layout (int32
 * words only, no padding). See the deviation record in docs/c-port.md.
 */
#ifndef ECU_CORE_H
#define ECU_CORE_H

#include <stddef.h>
#include <stdint.h>

/*
 * The constants shared with the Python firmware and the CAN contract, generated from their
 * definitions (python -m ecu.port.codegen): array lengths ECU_N_THETA, ECU_PI_POINTS,
 * ECU_SCHED_POINTS, ECU_RATE_BUF_LEN; theta slots ECU_AP21..ECU_KB; modes ECU_OFF..ECU_FAULT;
 * sequencer states ECU_SEQ_*; abort reasons ECU_ABORT_*; the logbook's length ECU_LOG_ABORTS and
 * shutdown reasons ECU_SD_*; the bench test functions ECU_TEST_* and their limits; controllers ECU_CTRL_*; E2E statuses
 * ECU_E2E_* (OK: a fresh valid frame, its values are used; REPEATED, WRONGSEQUENCE, WRONGCRC:
 * rejected, the values are not used; NONEWDATA: nothing arrived); loop owners ECU_OWNER_*; fault
 * word bits ECU_FAULT_*; the ECU's frame IDs, E2E data IDs and signal ranges.
 */
#include "generated/ecu_constants.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The four records, as X-macro lists (one list per record: the struct below, the Python
 * wrapper's field names and the golden-vector layout all come from these).
 * X(name) is one int32 field; A(name, n) an int32 array.
 */

/* ecu.firmware_params.FirmwareParams, in its order; init_theta_q24 holds the ECU_N_THETA start
 * values */
#define ECU_PARAM_FIELDS(X, A) \
    X(rate_hz) X(controller) X(dt_q24) X(rpm_to_q24_k) X(trim_n_q24) \
    X(trim_v_q24) X(entry_v_q24) X(am21_q24) X(am22_q24) X(idm11_q24) X(idm12_q24) \
    X(idm21_q24) X(idm22_q24) X(idh1_q24) X(idh2_q24) X(g_a1_q28) X(g_a2_q28) X(g_lam_q28) \
    X(g_th1_q28) X(g_th2_q28) A(init_theta_q24, ECU_N_THETA) X(lambda_comm_q24) X(health_alarm_pm) \
    X(rate_half_window) X(lambda_floor_on) X(lambda_floor_q24) X(dead_zone_on) \
    X(dead_zone_q24) X(freeze_on) X(adapt_band_q24) X(p12_ratio_q24) X(pump_scaling_on) \
    X(th_per_lam1_q28) X(th_per_lam2_q28) X(pump_v0_q24) X(lam_comm_v0_q16) X(g_b_q28) \
    X(ref_am21_q24) X(ref_am22_q24) X(ref_bm2_q24) \
    X(refm11_q24) X(refm12_q24) X(refm21_q24) X(refm22_q24) X(refh1_q24) X(refh2_q24) \
    X(g_x1_q28) X(g_x2_q28) X(g_r_q28) X(g_f1_q28) X(g_f2_q28) X(u_den_min_q24) \
    X(mrac_lag_c_q24) \
    X(pid_kp_q24) X(pid_ki_dt_q28) X(pid_kd_q24) \
    X(pi_n0_q24) X(pi_step_q24) A(pi_kp_q24, ECU_PI_POINTS) A(pi_ki_dt_q28, ECU_PI_POINTS) \
    X(fuel_schedules_on) X(sched_n0_q24) X(sched_step_q24) X(ncor_k_q24) X(inlet_from_egt) \
    A(accel_line_q24, ECU_SCHED_POINTS) A(decel_floor_q24, ECU_SCHED_POINTS) \
    A(accel_rate_q24, ECU_SCHED_POINTS) X(pump_dead_q24) X(sched_lam_lo_q24) X(sched_lam_hi_q24) X(idle_q24) X(demand_max_q24) \
    X(limiters_on) X(egt_limit_dk) X(egt_gas_margin_dk) X(egt_zero_fuel_dk) X(egt_engage_q24) X(rate_engage_q24) \
    X(n_limit_engage_q24) X(egt_kp_q24) X(egt_ki_dt_q24) X(egt_lead_cf_q16) X(egt_lead_ctc_q16) \
    X(egt_max_dk) X(egt_max_ticks) \
    X(accel_max_q24) X(decel_max_q24) X(rate_kp_q24) X(rate_ki_dt_q24) X(n_limit_q24) \
    X(n_limit_kp_q24) X(n_limit_ki_dt_q24) X(overspeed_rpm) X(overspeed_ticks) \
    X(flameout_rpm) X(flameout_ticks) X(flameout_egt_dk) X(flameout_egt_ticks) X(v_min_q24) \
    X(v_max_q24) X(v_slew_q24) \
    X(duty_min_cpct) X(duty_max_cpct) X(supply_nominal_mv) X(pump_stall_ma) X(pump_trip_ma) \
    X(pump_stall_ticks) X(pump_dry_base_ma) X(pump_dry_ma_per_v) X(pump_dry_min_q24) \
    X(pump_dry_ticks) X(speed_valid_max_rpm) X(speed_step_max_rpm) X(speed_fault_ticks) \
    X(speed_stuck_ticks) X(speed_stuck_dv_q24) X(egt_open_high_dk) X(egt_open_low_dk) \
    X(egt_fault_ticks) X(egt_fail_demand_q24) X(obs_l1_dt_q24) X(obs_l2_dt_q24) \
    X(rate_filter_on) X(rf_k1_q24) X(rf_k2_q24) X(rf_k3_q24) \
    X(demand_hold_ticks) X(demand_shutdown_ticks) X(sensor_loss_ticks) X(analog_loss_ticks) \
    X(run_entry_rpm) X(shutdown_done_rpm) \
    X(start_on) X(seq_start_cpct) X(seq_purge_ticks) X(seq_ign_rpm) X(seq_spinup_ticks) \
    X(seq_ign_v0_q24) X(seq_ign_v_step_q24) X(seq_ign_v_max_q24) X(seq_light_rise_dk) \
    X(seq_light_track_q8) X(seq_ign_ticks) X(seq_igniter_hold_ticks) X(seq_starter_step_cpct) \
    X(seq_ramp_v_step_q24) X(seq_accel_q24) X(seq_egt_target_dk) X(seq_hot_dk) X(seq_egt_cap_dk) X(seq_day_target_dk) \
    X(seq_cutoff_rpm) X(seq_ramp_ticks) X(seq_idle_rpm) X(seq_stabilise_ticks) \
    X(seq_relight_max) X(seq_cool_cpct) X(seq_cool_egt_dk) X(seq_cool_rearm_dk) \
    X(seq_cool_rpm) X(seq_cool_ticks) X(seq_soak_ticks)

/* ecu.state.EcuState, in its order (the state digest runs over these words in this order) */
#define ECU_STATE_FIELDS(X, A) \
    A(theta_q24, ECU_N_THETA) A(theta_ext, ECU_N_THETA) \
    A(n_hist_rpm, ECU_RATE_BUF_LEN) A(u_hist_q24, ECU_RATE_BUF_LEN) X(hist_idx) X(hist_fill) \
    X(xh1_q24) X(xh2_q24) X(e2_q24) X(obs_n_q24) X(obs_v_q24) \
    X(rf_n_q24) X(rf_v_q24) X(rf_a_q16) X(xm1_q24) X(xm2_q24) X(u_lag_q24) \
    X(egt_e_prev_q24) X(acc_e_prev_q24) X(dec_e_prev_q24) X(nlim_e_prev_q24) X(egt_lead_q12) \
    X(egt_vf_q24) \
    X(v_applied_q24) X(owner) X(v_saturated) X(line_owns) \
    X(speed_rpm) X(egt_dk) X(supply_mv) X(pump_ma) X(demand_q24) X(open_loop_q24) \
    X(arm) X(stop) X(sensor_age) X(analog_age) X(demand_age) \
    X(speed_range_cnt) X(speed_rate_cnt) X(speed_stuck_cnt) X(speed_stuck_v_q24) \
    X(egt_open_cnt) X(egt_over_cnt) X(overspeed_cnt) X(flameout_cnt) X(flame_egt_cnt) \
    X(pump_stall_cnt) X(pump_dry_cnt) X(speed_failed) X(speed_seen) X(inputs_seen) X(rearm_wait) \
    X(seq_state) X(seq_reason) X(seq_timer) X(seq_v_q24) X(seq_egt_ref_q8) X(relights) \
    X(starter_cpct) X(igniter) X(seq_target_dk) X(ncor_k_q24) \
    X(mode) X(faults) X(sat_events) X(ticks) \
    X(log_runs) X(log_run_time_s) X(log_run_frac_ticks) X(log_starts) \
    A(log_aborts, ECU_LOG_ABORTS) X(log_last_max_egt_dk) X(log_last_max_speed_cpct) \
    X(log_last_shutdown) X(log_in_run) \
    X(test_active) X(test_ticks_left) X(test_time_left_ms) X(test_level_held) X(test_request_last)

/* ecu.firmware.EcuInputs: raw integers in the CAN contract's units */
#define ECU_INPUT_FIELDS(X, A) \
    X(tick)          /* lockstep tick number of the sensor frame */ \
    X(speed_rpm)     /* shaft speed, rpm */ \
    X(egt_dk)        /* EGT, 0.1 K */ \
    X(supply_mv)     /* pump supply voltage, mV */ \
    X(pump_ma)       /* pump current, mA */ \
    X(demand_cpct)   /* speed demand, 0.01 %N */ \
    X(open_loop_mv)  /* pump voltage demand for the open-loop controller, mV */ \
    X(arm)           /* arm request bit */ \
    X(stop)          /* stop request bit */ \
    X(sensor_status) /* ECU_E2E_* of the sensor frame (speed, EGT), expected every tick */ \
    X(analog_status) /* ECU_E2E_* of the analog frame (supply, current), every 50 ms */ \
    X(demand_status) /* ECU_E2E_* of the demand frame (demand, open loop, arm, stop) */ \
    X(test_request)  /* bench test function, in OFF only: ECU_TEST_* (0: none / end) */ \
    X(test_level)    /* its level: starter duty 0.01 % (ECU_TEST_STARTER), pump mV (PRIME) */ \
    X(test_ms)       /* its duration, ms */

/* ecu.firmware.EcuOutputs */
#define ECU_OUTPUT_FIELDS(X, A) \
    X(tick)           /* echo of the input tick */ \
    X(duty_cpct)      /* pump PWM duty, 0.01 % (0..10000) */ \
    X(pump_mv)        /* pump voltage aimed for, mV */ \
    X(pump_enable)    /* pump driver enable */ \
    X(mode)           /* ECU_OFF .. ECU_FAULT */ \
    X(fault_word)     /* 16-bit fault word (ECU_FAULT_* bits, ecu/faults.py) */ \
    X(sat_events)     /* saturation events since power-on (saturating) */ \
    X(ap21_q24) X(ap22_q24) X(lambda_q24) X(theta21_q24) X(theta22_q24) \
    X(kx1_q24) X(kx2_q24) X(kr_q24) X(kf1_q24) X(kf2_q24) \
    X(pump_health_pm) /* Lambda-hat / commissioning Lambda, 0.1 % */ \
    X(nref_cpct)      /* reference-model speed, 0.01 %N */ \
    X(n_cpct)         /* speed used by the control, 0.01 %N */ \
    X(owner)          /* loop owning the pump command (ECU_OWNER_*) */ \
    X(starter_cpct)   /* starter PWM duty, 0.01 % (0..10000) */ \
    X(igniter)        /* igniter power bit */ \
    X(seq_state)      /* start/stop sequencer state (ECU_SEQ_*) */ \
    X(seq_reason)     /* the last start's abort reason (ECU_ABORT_*, 0: none) */ \
    X(inputs_valid)   /* 1 once valid speed and EGT readings came since power-up */

#define ECU_X_FIELD(name) int32_t name;
#define ECU_A_FIELD(name, n) int32_t name[n];
#define ECU_X_COUNT(name) +1
#define ECU_A_COUNT(name, n) +(n)

typedef struct { ECU_PARAM_FIELDS(ECU_X_FIELD, ECU_A_FIELD) } ecu_params_t;
typedef struct { ECU_STATE_FIELDS(ECU_X_FIELD, ECU_A_FIELD) } ecu_state_t;
typedef struct { ECU_INPUT_FIELDS(ECU_X_FIELD, ECU_A_FIELD) } ecu_inputs_t;
typedef struct { ECU_OUTPUT_FIELDS(ECU_X_FIELD, ECU_A_FIELD) } ecu_outputs_t;

enum {
    ECU_PARAM_WORDS = 0 ECU_PARAM_FIELDS(ECU_X_COUNT, ECU_A_COUNT),
    ECU_STATE_WORDS = 0 ECU_STATE_FIELDS(ECU_X_COUNT, ECU_A_COUNT),
    ECU_INPUT_WORDS = 0 ECU_INPUT_FIELDS(ECU_X_COUNT, ECU_A_COUNT),
    ECU_OUTPUT_WORDS = 0 ECU_OUTPUT_FIELDS(ECU_X_COUNT, ECU_A_COUNT)
};

/* One ECU instance: parameters (not owned), state, outputs and the sticky saturation count. */
typedef struct {
    const ecu_params_t *p;
    ecu_state_t s;
    ecu_outputs_t o;
    int32_t sat_pending; /* saturation events not yet added to s.sat_events (ARM Q flag) */
    int32_t rate_q24;    /* the last tick's speed rate, %N/s (TickVars.rate: a measurement) */
} ecu_t;

/*
 * Fill *p from n int32 words in ECU_PARAM_FIELDS order and check what the tick relies on.
 * Returns -1 when accepted; otherwise the index of the first offending word (or
 * ECU_PARAM_WORDS when n is wrong), and *p must not be used.
 */
int ecu_params_load(ecu_params_t *p, const int32_t *words, size_t n);

/* Power-on initialisation (also the only way out of a latched FAULT). */
void ecu_init(ecu_t *e, const ecu_params_t *p);

/* One control step; returns the instance's output record (valid until the next tick). */
const ecu_outputs_t *ecu_tick(ecu_t *e, const ecu_inputs_t *in);

/* FNV-1a (32-bit) over the ECU_STATE_WORDS state words, as ecu/golden.py computes it. */
uint32_t ecu_state_digest(const ecu_state_t *s);

#ifdef ECU_STAGE_PROFILE
/* The tick's stages, in their order (ecu/firmware.py Ecu.tick). Built with ECU_STAGE_PROFILE,
 * ecu_tick calls ecu_stage_done(stage) at the end of each stage it runs (control law and limit
 * selection in RUN only); you provide it (the Cortex-M4 replayer counts SysTick with it). */
enum {
    ECU_STAGE_SENSORS,
    ECU_STAGE_HISTORY,
    ECU_STAGE_TRIPS,
    ECU_STAGE_START_SEQUENCER,
    ECU_STAGE_MODE,
    ECU_STAGE_CONTROL_LAW,
    ECU_STAGE_LIMIT_SELECTION,
    ECU_STAGE_PUMP_DRIVER,
    ECU_STAGE_ACTUATOR_TESTS,
    ECU_STAGE_HEALTH,
    ECU_STAGE_LOGBOOK,
    ECU_STAGES
};
void ecu_stage_done(int stage);
#endif

#ifdef ECU_WITH_NAMES
/* Field names, space separated, of each record (host builds: the Python wrapper checks them). */
extern const char ecu_param_names[];
extern const char ecu_state_names[];
extern const char ecu_input_names[];
extern const char ecu_output_names[];
#endif

#ifdef __cplusplus
}
#endif
#endif /* ECU_CORE_H */
