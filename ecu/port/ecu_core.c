/*
 * ecu_core.c - the ECU tick, function by function as in the Python modules (named above each
 * group). See ecu_core.h for the API and ecu/fixedpoint.py for the arithmetic conventions.
 */
#include "ecu_core.h"

#include <limits.h>
#include <string.h>

/* ---- what the port relies on, checked at compile time (docs/c-port.md, deviations) --------- */

#if (-1 >> 1) != -1
#error "ecu_core needs arithmetic right shift of negative values"
#endif
#if INT_MAX < 2147483647
#error "ecu_core needs an int of at least 32 bits"
#endif

/* A compile-time assertion: C11's _Static_assert, else (the builds are C99) a typedef of an
 * array whose size is negative when cond is false. name is unique per assertion. */
#if defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L
#define ECU_STATIC_ASSERT(cond, name) _Static_assert(cond, #name)
#else
#define ECU_STATIC_ASSERT(cond, name) typedef char ecu_static_assert_##name[(cond) ? 1 : -1]
#endif

/* right shifts of negative values are arithmetic in the compiler's own constant arithmetic
 * too, at both widths the tick shifts (implementation-defined in C99 6.5.7; not undefined) */
ECU_STATIC_ASSERT(((int32_t)-5 >> 1) == -3, arithmetic_shift_int32);
ECU_STATIC_ASSERT(((int64_t)-5 >> 1) == -3 && (INT64_MIN >> 62) == -2, arithmetic_shift_int64);

/* The records are int32 words and nothing else: no padding (their size is exactly their word
 * count), aligned as int32_t. ecu_params_load and ecu_state_digest read them as those words
 * (memcpy of the object representation, in member order: C99 6.7.2.1), the Python wrapper
 * (ecu/port/core.py) lays them out as ctypes int32 fields and the golden vectors as words. */
typedef struct { char c; int32_t r; } ecu_align_int32_t;
typedef struct { char c; ecu_params_t r; } ecu_align_params_t;
typedef struct { char c; ecu_state_t r; } ecu_align_state_t;
typedef struct { char c; ecu_inputs_t r; } ecu_align_inputs_t;
typedef struct { char c; ecu_outputs_t r; } ecu_align_outputs_t;
ECU_STATIC_ASSERT(sizeof(ecu_params_t) == ECU_PARAM_WORDS * sizeof(int32_t), params_no_padding);
ECU_STATIC_ASSERT(sizeof(ecu_state_t) == ECU_STATE_WORDS * sizeof(int32_t), state_no_padding);
ECU_STATIC_ASSERT(sizeof(ecu_inputs_t) == ECU_INPUT_WORDS * sizeof(int32_t), inputs_no_padding);
ECU_STATIC_ASSERT(sizeof(ecu_outputs_t) == ECU_OUTPUT_WORDS * sizeof(int32_t),
                  outputs_no_padding);
ECU_STATIC_ASSERT(offsetof(ecu_align_params_t, r) == offsetof(ecu_align_int32_t, r),
                  params_int32_aligned);
ECU_STATIC_ASSERT(offsetof(ecu_align_state_t, r) == offsetof(ecu_align_int32_t, r),
                  state_int32_aligned);
ECU_STATIC_ASSERT(offsetof(ecu_align_inputs_t, r) == offsetof(ecu_align_int32_t, r),
                  inputs_int32_aligned);
ECU_STATIC_ASSERT(offsetof(ecu_align_outputs_t, r) == offsetof(ecu_align_int32_t, r),
                  outputs_int32_aligned);

/* take_egt_at_rest: ECU_T_STD_CK << 48 fits an int64 (ECU_T_STD_CK < 2^15: the product is
 * below 2^63), the day's temperature in 0.01 K fits an int32 and is never 0, and the quotient
 * (ECU_T_STD_CK << 48) / inlet_ck stays under 2^62 at the coldest inlet, so its square root
 * (1 / sqrt(theta) in Q24) fits an int32 */
ECU_STATIC_ASSERT(ECU_T_STD_CK > 0 && ECU_T_STD_CK < (1 << 15), t_std_shift_fits_int64);
ECU_STATIC_ASSERT(ECU_INLET_MIN_DK > 0 && ECU_INLET_MIN_DK <= ECU_INLET_MAX_DK &&
                      ECU_INLET_MAX_DK <= INT32_MAX / 10,
                  inlet_range_fits_int32);
ECU_STATIC_ASSERT(((int64_t)ECU_T_STD_CK << 48) / (ECU_INLET_MIN_DK * 10) < ((int64_t)1 << 62),
                  ncor_k_fits_int32);

/* Helpers called from several places that are worth no call frame of their own: forced inline
 * (C99's inline is only a hint, which gcc -Os does not take for these). The tick's stack bound
 * is the sum of the frames of every function here (sil/port_bench.py), within the 2 KiB of RAM
 * the core, its parameters and its stack are given. */
#if defined(__GNUC__)
#define ECU_INLINE static inline __attribute__((always_inline))
#else
#define ECU_INLINE static inline
#endif

/* ---- ecu/fixedpoint.py --------------------------------------------------------------------- */

#define ONE_Q24 ((int64_t)1 << 24)

/* x out of the int32 range: counted, the nearest bound */
static int32_t sat32_out(ecu_t *e, int64_t x)
{
    e->sat_pending++;
    return x > 0 ? INT32_MAX : INT32_MIN;
}

/* x saturated to int32, an x out of range counted: the in-range test inline (the tick
 * saturates some fifty values), the rare rest a call */
ECU_INLINE int32_t sat32(ecu_t *e, int64_t x)
{
    return x == (int32_t)x ? (int32_t)x : sat32_out(e, x);
}

/* a control limit, not an overflow: not counted */
static int64_t clamp(int64_t x, int64_t lo, int64_t hi)
{
    return x < lo ? lo : (x > hi ? hi : x);
}

#define U48 ((uint64_t)1 << 48)
#define U16 ((uint32_t)1 << 16)

/* The tick's divisions without the library's 64-bit division (a call of some 60 instructions on
 * a Cortex-M4): a 64-bit magnitude by a divisor of 32 bits, in the core's unsigned 32-bit
 * divisions (UDIV). */

/* the number of leading zero bits of x != 0 (CLZ on a Cortex-M4) */
ECU_INLINE unsigned clz32(uint32_t x)
{
#if defined(__GNUC__)
    return (unsigned)__builtin_clz(x);
#else
    unsigned n = 0;
    while (!(x & 0x80000000u)) {
        x <<= 1;
        n++;
    }
    return n;
#endif
}

/* (u1 2^32 + u0) / v for u1 < v (the quotient fits 32 bits), exactly: long division in two
 * base-2^16 digits on the normalised operands (Knuth's algorithm D, as Hacker's Delight's
 * divlu), each digit estimated by a 32-bit division and corrected at most twice. The products
 * and shifts wrap modulo 2^32 where the algorithm lets them (un32 << 16). */
static uint32_t udiv_2by1(uint32_t u1, uint32_t u0, uint32_t v)
{
    unsigned sh = clz32(v);
    uint32_t vn1, vn0, un32, un10, un1, un0, q1, q0, rhat, un21;
    v <<= sh;
    vn1 = v >> 16;
    vn0 = v & 0xFFFFu;
    un32 = sh ? u1 << sh | u0 >> (32u - sh) : u1;
    un10 = u0 << sh;
    un1 = un10 >> 16;
    un0 = un10 & 0xFFFFu;
    q1 = un32 / vn1;
    rhat = un32 - q1 * vn1;
    while (q1 >= U16 || q1 * vn0 > (rhat << 16) + un1) {
        q1--;
        rhat += vn1;
        if (rhat >= U16) {
            break;
        }
    }
    un21 = (un32 << 16) + un1 - q1 * v;
    q0 = un21 / vn1;
    rhat = un21 - q0 * vn1;
    while (q0 >= U16 || q0 * vn0 > (rhat << 16) + un0) {
        q0--;
        rhat += vn1;
        if (rhat >= U16) {
            break;
        }
    }
    return q1 << 16 | q0;
}

/* a / v for 0 < v < 2^32, exactly: the high word's quotient, then its remainder and the low
 * word by udiv_2by1 */
static uint64_t udiv64_32(uint64_t a, uint32_t v)
{
    uint32_t hi = (uint32_t)(a >> 32);
    uint32_t q_hi = hi / v;
    return (uint64_t)q_hi << 32 | udiv_2by1(hi - q_hi * v, (uint32_t)a, v);
}

/* a / b for a < 2^48 and 0 < b < 2^16, exactly, by long division in two base-2^16 digits: the
 * high part's remainder r < b keeps (r << 16) + the low digit under 2^32 */
ECU_INLINE uint32_t udiv48_by16(uint64_t a, uint32_t b, uint32_t *q_hi)
{
    uint32_t hi = (uint32_t)(a >> 16);
    uint32_t lo;
    *q_hi = hi / b;
    lo = (hi - *q_hi * b) << 16 | (uint32_t)(a & 0xFFFFu);
    return lo / b;
}

/* a / b truncated toward zero, saturated; b == 0 saturates with the dividend's sign. Every
 * call has |a| < 2^63 and |b| < 2^32 (at most a difference of two int32): the magnitudes'
 * quotient, 2^32 standing for any quotient that saturates; the tick's small divisors (rate
 * windows, the supply in mV, decimal scales) by udiv48_by16 */
static int32_t div_trunc(ecu_t *e, int64_t a, int64_t b)
{
    uint64_t ua = a < 0 ? 0u - (uint64_t)a : (uint64_t)a;
    uint32_t ub = (uint32_t)(b < 0 ? 0u - (uint64_t)b : (uint64_t)b);
    uint32_t hi, lo;
    int64_t q;
    if (b == 0) {
        e->sat_pending++;
        return a > 0 ? INT32_MAX : (a < 0 ? INT32_MIN : 0);
    }
    if (ub < U16 && ua < U48) {
        lo = udiv48_by16(ua, ub, &hi);
        q = (int64_t)hi * U16 + lo;
    } else {
        hi = (uint32_t)(ua >> 32);
        q = hi >= ub ? (int64_t)1 << 32 : (int64_t)udiv_2by1(hi, (uint32_t)ua, ub);
    }
    return sat32(e, (a < 0) != (b < 0) ? -q : q);
}

/* (a * b) >> s exactly where a * b itself may exceed 64 bits (|a| < 2^55 for b of 32 bits):
 * split a at k = min(s, 24) bits, a = hi 2^k + lo, and shift the two partial products */
static int64_t mul_wide_shr(int64_t a, int32_t b, unsigned s)
{
    unsigned k = s < 24u ? s : 24u;
    int64_t hi = a >> k;
    int64_t lo = a & (((int64_t)1 << k) - 1);
    return (hi * b + ((lo * b) >> k)) >> (s - k);
}

/* split accumulator (hi, lo) = Q7.40 in two int32 words (ECU_ACC_EXT_BITS of the extension
 * below the Q7.24 word), plus a Q7.40 increment */
static void acc_q40(ecu_t *e, int32_t *hi, int32_t *lo, int64_t inc_q40)
{
    int64_t total = (int64_t)*hi * ((int64_t)1 << ECU_ACC_EXT_BITS) + *lo + inc_q40;
    int64_t h = total >> ECU_ACC_EXT_BITS;
    if (h > INT32_MAX || h < INT32_MIN) {
        *hi = sat32(e, h);
        *lo = 0;
        return;
    }
    *hi = (int32_t)h;
    *lo = (int32_t)(total & (((int64_t)1 << ECU_ACC_EXT_BITS) - 1));
}

static int32_t mul_q24(ecu_t *e, int32_t a, int32_t b)
{
    return sat32(e, ((int64_t)a * b) >> 24);
}

/* ---- ecu/faults.py ------------------------------------------------------------------------- */

static int32_t persist(int32_t count, int bad, int32_t limit)
{
    if (bad) {
        return count < limit ? count + 1 : limit;
    }
    return count > 0 ? count - 1 : 0;
}

static int32_t speed_checks(ecu_t *e, int32_t rpm, int32_t prev_rpm, int32_t v_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int64_t step = (int64_t)rpm - prev_rpm;
    int32_t tripped = 0;
    s->speed_range_cnt = persist(s->speed_range_cnt, rpm < 0 || rpm > p->speed_valid_max_rpm,
                                 p->speed_fault_ticks);
    s->speed_rate_cnt = persist(s->speed_rate_cnt,
                                step > p->speed_step_max_rpm || step < -(int64_t)p->speed_step_max_rpm,
                                p->speed_fault_ticks);
    if (rpm != prev_rpm) {
        s->speed_stuck_cnt = 0;
        s->speed_stuck_v_q24 = v_q24;
    } else {
        int64_t dv = (int64_t)v_q24 - s->speed_stuck_v_q24;
        int moved = dv > p->speed_stuck_dv_q24 || dv < -(int64_t)p->speed_stuck_dv_q24;
        s->speed_stuck_cnt = persist(s->speed_stuck_cnt, moved, p->speed_stuck_ticks);
    }
    if (s->speed_range_cnt >= p->speed_fault_ticks) {
        tripped |= ECU_FAULT_SPEED_RANGE;
    }
    if (s->speed_rate_cnt >= p->speed_fault_ticks) {
        tripped |= ECU_FAULT_SPEED_RATE;
    }
    if (s->speed_stuck_cnt >= p->speed_stuck_ticks) {
        tripped |= ECU_FAULT_SPEED_STUCK;
    }
    return tripped;
}

static int32_t egt_open_check(ecu_t *e, int32_t egt_dk)
{
    const ecu_params_t *p = e->p;
    int bad = egt_dk > p->egt_open_high_dk || egt_dk < p->egt_open_low_dk;
    e->s.egt_open_cnt = persist(e->s.egt_open_cnt, bad, p->egt_fault_ticks);
    return e->s.egt_open_cnt >= p->egt_fault_ticks ? ECU_FAULT_EGT_OPEN : 0;
}

/* the sensors whose fresh reading is plausible (SEEN_*): speed in its valid range, EGT not
   railed as an open thermocouple reads */
static int32_t valid_readings(const ecu_params_t *p, int32_t rpm, int32_t egt_dk)
{
    int32_t seen = rpm >= 0 && rpm <= p->speed_valid_max_rpm ? ECU_SEEN_SPEED : 0;
    if (egt_dk >= p->egt_open_low_dk && egt_dk <= p->egt_open_high_dk) {
        seen |= ECU_SEEN_EGT;
    }
    return seen;
}

/* ---- ecu/pump_driver.py -------------------------------------------------------------------- */

static int32_t volts_q24_to_mv(int32_t v_q24)
{
    return (int32_t)(((int64_t)v_q24 * 1000 + (1 << 23)) >> 24);
}

static int32_t pump_duty(ecu_t *e, int32_t v_mv, int32_t supply_mv)
{
    const ecu_params_t *p = e->p;
    int32_t duty = supply_mv > 0 ? div_trunc(e, (int64_t)v_mv * 10000, supply_mv)
                                 : p->duty_max_cpct;
    int32_t limited = (int32_t)clamp(duty, p->duty_min_cpct, p->duty_max_cpct);
    if (limited != duty) {
        e->s.v_saturated = 1;
    }
    return limited;
}

static int32_t pump_current_checks(ecu_t *e, int32_t pump_ma, int32_t v_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int applied = v_q24 > p->pump_dry_min_q24;
    int stall = pump_ma > p->pump_stall_ma || (applied && pump_ma < p->pump_trip_ma);
    int64_t dry_ma;
    int dry;
    int32_t tripped = 0;
    s->pump_stall_cnt = persist(s->pump_stall_cnt, stall, p->pump_stall_ticks);
    dry_ma = (int64_t)p->pump_dry_base_ma +
             div_trunc(e, (int64_t)p->pump_dry_ma_per_v * volts_q24_to_mv(v_q24), 1000);
    dry = applied && p->pump_trip_ma <= pump_ma && pump_ma < dry_ma;
    s->pump_dry_cnt = persist(s->pump_dry_cnt, dry, p->pump_dry_ticks);
    if (s->pump_stall_cnt >= p->pump_stall_ticks) {
        tripped |= ECU_FAULT_PUMP_STALL;
    }
    if (s->pump_dry_cnt >= p->pump_dry_ticks) {
        tripped |= ECU_FAULT_PUMP_DRY;
    }
    return tripped;
}

/* ---- ecu/estimator.py (eq. 4.7, 4.31) ------------------------------------------------------ */

/* d0 = (Lambda-hat - Lambda_c) (V0 - V_d), %N/s^2 (Q15.16); 0 without pump scaling */
#define R32 ((int64_t)1 << 31) /* half an LSB before >> 32: round to nearest, ties up */
#define R24 ((int64_t)1 << 23)

/* eq. 4.31's step -(Gamma P dt) phi e in Q7.40, rounded to nearest */
static int64_t increment_q40(int32_t phi_e_q16, int32_t gain_q28)
{
    return (-(int64_t)phi_e_q16 * gain_q28 + 8) >> 4;
}

ECU_INLINE int32_t pump_bias_q16(ecu_t *e)
{
    const ecu_params_t *p = e->p;
    if (!p->pump_scaling_on) {
        return 0;
    }
    return sat32(e, (((int64_t)e->s.theta_q24[ECU_LAM] * p->pump_v0_q24) >> 32) -
                        p->lam_comm_v0_q16);
}

/* g(dN) = 1 + r1 dN + r2 dN^2 (Q7.24) from dN (Q7.24) and dN^2 (Q15.16) */
static int32_t fuel_shape_q24(ecu_t *e, int32_t n_q24, int64_t nn_q16)
{
    const ecu_params_t *p = e->p;
    return sat32(e, ONE_Q24 + (((int64_t)p->th_per_lam1_q28 * n_q24) >> 28) +
                        ((p->th_per_lam2_q28 * nn_q16) >> 20));
}

static void estimator_step(ecu_t *e, int32_t n0, int32_t v0, int32_t n1, int32_t v1, int32_t u,
                           int adapt)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t *th = s->theta_q24;
    int32_t *ext = s->theta_ext;
    int32_t n_mid = (int32_t)(((int64_t)n0 + n1) >> 1);
    int32_t v_mid = (int32_t)(((int64_t)v0 + v1) >> 1);
    int32_t f1 = mul_q24(e, u, n_mid);
    int64_t nn_q16 = (((int64_t)n0 * n0) >> 33) + (((int64_t)n1 * n1) >> 33);
    int32_t f2_q16 = sat32(e, (u * nn_q16) >> 24);
    int32_t g = fuel_shape_q24(e, n_mid, nn_q16);
    int32_t c2_q16 = sat32(e, ((((int64_t)th[ECU_AP21] - p->am21_q24) * n_mid) >> 32) +
                                  ((((int64_t)th[ECU_AP22] - p->am22_q24) * v_mid) >> 32) +
                                  (((int64_t)th[ECU_LAM] * u) >> 32) +
                                  (((int64_t)th[ECU_TH1] * f1) >> 32) +
                                  (((int64_t)th[ECU_TH2] * f2_q16) >> 24) +
                                  (((int64_t)pump_bias_q16(e) * g) >> 24));
    int32_t xh1 = s->xh1_q24;
    int32_t xh2 = s->xh2_q24;
    int32_t e2;
    int32_t err;
    s->xh1_q24 = sat32(e, (((int64_t)p->idm11_q24 * xh1) >> 24) +
                              (((int64_t)p->idm12_q24 * xh2) >> 24) +
                              (((int64_t)p->idh1_q24 * c2_q16) >> 16));
    s->xh2_q24 = sat32(e, (((int64_t)p->idm21_q24 * xh1) >> 24) +
                              (((int64_t)p->idm22_q24 * xh2) >> 24) +
                              (((int64_t)p->idh2_q24 * c2_q16) >> 16));
    e2 = sat32(e, (int64_t)s->xh2_q24 - v1);
    s->e2_q24 = e2;
    if (!adapt) {
        return;
    }
    /* (P e)_2 / p22: the error that drives eq. 4.31 */
    err = sat32(e, (int64_t)e2 + (((int64_t)p->p12_ratio_q24 *
                                   sat32(e, (int64_t)s->xh1_q24 - n1)) >> 24));
    if (p->dead_zone_on && -p->dead_zone_q24 < err && err < p->dead_zone_q24) {
        return;
    }
    /* increments in Q7.40: phi e in Q15.16 times Gamma P dt in Q3.28, >> 4, each rounded to
       nearest (a truncation's half-LSB bias per tick would drift the estimates) */
    acc_q40(e, &th[ECU_AP21], &ext[ECU_AP21],
            increment_q40(sat32(e, ((int64_t)n_mid * err + R32) >> 32), p->g_a1_q28));
    acc_q40(e, &th[ECU_AP22], &ext[ECU_AP22],
            increment_q40(sat32(e, ((int64_t)v_mid * err + R32) >> 32), p->g_a2_q28));
    if (p->pump_scaling_on) {
        int32_t phi = sat32(e, ((int64_t)g * ((int64_t)u + p->pump_v0_q24)) >> 24);
        acc_q40(e, &th[ECU_LAM], &ext[ECU_LAM],
                increment_q40(sat32(e, ((int64_t)phi * err + R32) >> 32), p->g_lam_q28));
    } else {
        acc_q40(e, &th[ECU_LAM], &ext[ECU_LAM],
                increment_q40(sat32(e, ((int64_t)u * err + R32) >> 32), p->g_lam_q28));
        acc_q40(e, &th[ECU_TH1], &ext[ECU_TH1],
                increment_q40(sat32(e, ((int64_t)f1 * err + R32) >> 32), p->g_th1_q28));
        acc_q40(e, &th[ECU_TH2], &ext[ECU_TH2],
                increment_q40(sat32(e, ((int64_t)f2_q16 * err + R24) >> 24), p->g_th2_q28));
    }
    if (p->lambda_floor_on && th[ECU_LAM] < p->lambda_floor_q24) {
        th[ECU_LAM] = p->lambda_floor_q24;
        ext[ECU_LAM] = 0;
    }
    if (p->pump_scaling_on) { /* Theta_f-hat = Lambda-hat r */
        th[ECU_TH1] = sat32(e, ((int64_t)th[ECU_LAM] * p->th_per_lam1_q28) >> 28);
        th[ECU_TH2] = sat32(e, ((int64_t)th[ECU_LAM] * p->th_per_lam2_q28) >> 28);
        ext[ECU_TH1] = 0;
        ext[ECU_TH2] = 0;
    }
}

/* ---- ecu/mrac.py (eq. 5.4, 5.15-5.16, 5.18-5.19) ------------------------------------------- */

static int32_t mrac_control(ecu_t *e, int32_t dn, int32_t dv, int32_t r)
{
    const int32_t *th = e->s.theta_q24;
    int32_t num = sat32(e, (((int64_t)th[ECU_KX1] * dn) >> 24) +
                               (((int64_t)th[ECU_KX2] * dv) >> 24) +
                               (((int64_t)th[ECU_KR] * r) >> 24));
    int64_t kf2_dn = ((int64_t)th[ECU_KF2] * dn) >> 24;
    int32_t den = sat32(e, ONE_Q24 - (((int64_t)th[ECU_KF1] * dn) >> 24) -
                               mul_wide_shr(kf2_dn, dn, 24));
    if (den < e->p->u_den_min_q24) {
        den = e->p->u_den_min_q24;
    }
    return sat32(e, (int64_t)div_trunc(e, (int64_t)num * ONE_Q24, den) + th[ECU_KB]);
}

/* command_lag: the MRAC's command through the first-order lag of mrac_cmd_lag_s (backward Euler,
 * c = dt / (tau + dt) in Q24; c = 1 passes u): lag and engine are then the fast model */
ECU_INLINE int32_t command_lag(ecu_t *e, int32_t u)
{
    ecu_state_t *s = &e->s;
    s->u_lag_q24 = sat32(e, (int64_t)s->u_lag_q24 +
                                (((int64_t)e->p->mrac_lag_c_q24 * ((int64_t)u - s->u_lag_q24)) >> 24));
    return s->u_lag_q24;
}

static void mrac_gain_update(ecu_t *e)
{
    const ecu_params_t *p = e->p;
    int32_t *th = e->s.theta_q24;
    int32_t *ext = e->s.theta_ext;
    int64_t lam = th[ECU_LAM];
    int32_t eps;
    eps = sat32(e, (int64_t)th[ECU_AP21] - p->ref_am21_q24 + ((lam * th[ECU_KX1]) >> 24));
    acc_q40(e, &th[ECU_KX1], &ext[ECU_KX1], (-(int64_t)eps * p->g_x1_q28) >> 12);
    eps = sat32(e, (int64_t)th[ECU_AP22] - p->ref_am22_q24 + ((lam * th[ECU_KX2]) >> 24));
    acc_q40(e, &th[ECU_KX2], &ext[ECU_KX2], (-(int64_t)eps * p->g_x2_q28) >> 12);
    eps = sat32(e, -(int64_t)p->ref_bm2_q24 + ((lam * th[ECU_KR]) >> 24));
    acc_q40(e, &th[ECU_KR], &ext[ECU_KR], (-(int64_t)eps * p->g_r_q28) >> 12);
    eps = sat32(e, (int64_t)th[ECU_TH1] + ((lam * th[ECU_KF1]) >> 24));
    acc_q40(e, &th[ECU_KF1], &ext[ECU_KF1], (-(int64_t)eps * p->g_f1_q28) >> 12);
    eps = sat32(e, (int64_t)th[ECU_TH2] + ((lam * th[ECU_KF2]) >> 24));
    acc_q40(e, &th[ECU_KF2], &ext[ECU_KF2], (-(int64_t)eps * p->g_f2_q28) >> 12);
    eps = sat32(e, (int64_t)pump_bias_q16(e) * 256 + ((lam * th[ECU_KB]) >> 24));
    acc_q40(e, &th[ECU_KB], &ext[ECU_KB], (-(int64_t)eps * p->g_b_q28) >> 12);
}

static void reference_model_step(ecu_t *e, int32_t r)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int64_t xm1 = s->xm1_q24;
    int64_t xm2 = s->xm2_q24;
    s->xm1_q24 = sat32(e, ((p->refm11_q24 * xm1) >> 24) + ((p->refm12_q24 * xm2) >> 24) +
                              (((int64_t)p->refh1_q24 * r) >> 24));
    s->xm2_q24 = sat32(e, ((p->refm21_q24 * xm1) >> 24) + ((p->refm22_q24 * xm2) >> 24) +
                              (((int64_t)p->refh2_q24 * r) >> 24));
}

/* ---- ecu/pid.py ---------------------------------------------------------------------------- */

static int32_t pid_control(ecu_t *e, int32_t err, int32_t dv)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    acc_q40(e, &s->theta_q24[ECU_PID_I], &s->theta_ext[ECU_PID_I],
            ((int64_t)err * p->pid_ki_dt_q28) >> 12);
    return sat32(e, (((int64_t)p->pid_kp_q24 * err) >> 24) + s->theta_q24[ECU_PID_I] -
                        (((int64_t)p->pid_kd_q24 * dv) >> 24));
}

static void pid_track(ecu_t *e, int32_t err, int32_t dv, int32_t u_applied)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    s->theta_q24[ECU_PID_I] = sat32(e, (int64_t)u_applied - (((int64_t)p->pid_kp_q24 * err) >> 24) +
                                           (((int64_t)p->pid_kd_q24 * dv) >> 24));
    s->theta_ext[ECU_PID_I] = 0;
}

/* ---- ecu/tables.py ------------------------------------------------------------------------- */

static int32_t interp_uniform(ecu_t *e, const int32_t *table, int32_t n, int32_t x0_q24,
                              int32_t step_q24, int32_t x_q24)
{
    int64_t x = (int64_t)x_q24 - x0_q24;
    uint32_t k, f;
    if (x <= 0) {
        return table[0];
    }
    /* 0 < x < 2^32 and step >= 1 (ecu_params_load): Python's x // step, exactly, in one
     * unsigned 32-bit division (UDIV on a Cortex-M4) */
    k = (uint32_t)x / (uint32_t)step_q24;
    if (k >= (uint32_t)(n - 1)) {
        return table[n - 1];
    }
    f = (uint32_t)x - k * (uint32_t)step_q24;
    return sat32(e, (int64_t)table[k] +
                        div_trunc(e, ((int64_t)table[k + 1] - table[k]) * f, step_q24));
}

/* ---- ecu/pi.py ----------------------------------------------------------------------------- */

ECU_INLINE int32_t scheduled(ecu_t *e, const int32_t *table, int32_t n_q24)
{
    return interp_uniform(e, table, ECU_PI_POINTS, e->p->pi_n0_q24, e->p->pi_step_q24, n_q24);
}

static int32_t pi_control(ecu_t *e, int32_t err, int32_t n_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    acc_q40(e, &s->theta_q24[ECU_PID_I], &s->theta_ext[ECU_PID_I],
            ((int64_t)err * scheduled(e, p->pi_ki_dt_q28, n_q24)) >> 12);
    return sat32(e, (((int64_t)scheduled(e, p->pi_kp_q24, n_q24) * err) >> 24) +
                        s->theta_q24[ECU_PID_I]);
}

static void pi_track(ecu_t *e, int32_t err, int32_t n_q24, int32_t u_applied)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    s->theta_q24[ECU_PID_I] =
        sat32(e, (int64_t)u_applied - (((int64_t)scheduled(e, p->pi_kp_q24, n_q24) * err) >> 24));
    s->theta_ext[ECU_PID_I] = 0;
}

/* ---- ecu/limiters.py ----------------------------------------------------------------------- */

/* the gas temperature from the thermocouple's reading (ecu/limiters.py egt_lead_step): the lead
 * (T_tc s + 1)/(T_f s + 1) by backward Euler, y in 0.1 K Q12; called before s->egt_dk takes x */
static void egt_lead_step(ecu_t *e, int32_t egt_dk)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int64_t x_q12 = (int64_t)egt_dk * 4096;
    int64_t y = s->egt_lead_q12;
    if (y == 0) { /* the first reading: no history to lead on */
        s->egt_lead_q12 = sat32(e, x_q12);
        return;
    }
    y += ((int64_t)p->egt_lead_cf_q16 * (x_q12 - y)) >> 16;
    s->egt_lead_q12 =
        sat32(e, y + (((int64_t)p->egt_lead_ctc_q16 * ((int64_t)egt_dk - s->egt_dk)) >> 4));
}

/* a limit loop's voltage, its P part only while it owns the command (ecu/limiters.py _loop) */
static int32_t limit_loop(ecu_t *e, int64_t v_prev, int64_t err, int64_t err_prev, int32_t kp_q24,
                          int32_t ki_dt_q24, int owns)
{
    int64_t p_part = owns ? (kp_q24 * (err - err_prev)) >> 24 : 0;
    return sat32(e, v_prev + p_part + ((ki_dt_q24 * err) >> 24));
}

/* a schedule's table at corrected speed N / sqrt(theta) for the speed n_q24 (Q7.24), theta of
 * the day's inlet temperature (ecu/inlet.py) */
ECU_INLINE int32_t schedule_at(ecu_t *e, const int32_t *table, int32_t n_q24)
{
    const ecu_params_t *p = e->p;
    int32_t n_cor = sat32(e, ((int64_t)n_q24 * e->s.ncor_k_q24) >> 24);
    return interp_uniform(e, table, ECU_SCHED_POINTS, p->sched_n0_q24, p->sched_step_q24, n_cor);
}

static int32_t schedule_v(ecu_t *e, const int32_t *table, int32_t n_q24, int32_t lam_lo,
                          int32_t lam_hi)
{
    const ecu_params_t *p = e->p;
    int32_t v = schedule_at(e, table, n_q24);
    int32_t lam;
    if (!p->pump_scaling_on) {
        return v;
    }
    lam = (int32_t)clamp(e->s.theta_q24[ECU_LAM], lam_lo, lam_hi);
    return sat32(e, (int64_t)p->pump_dead_q24 +
                        div_trunc(e, ((int64_t)v - p->pump_dead_q24) * p->lambda_comm_q24, lam));
}

/* pump_from_start: at the hand-over from a start at speed n_q24 and pump voltage v_q24, a start
 * that needed more than the commissioned pump's acceleration line has a weaker pump: Lambda-hat
 * starts at Lambda_c (V_line - V_d) / (V - V_d), and the line with it */
static void pump_from_start(ecu_t *e, int32_t n_q24, int32_t v_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t line = schedule_at(e, p->accel_line_q24, n_q24);
    int32_t lam;
    if (v_q24 > line && line > p->pump_dead_q24) {
        lam = div_trunc(e, ((int64_t)line - p->pump_dead_q24) * p->lambda_comm_q24,
                        (int64_t)v_q24 - p->pump_dead_q24);
        if (lam < p->sched_lam_lo_q24) {
            lam = p->sched_lam_lo_q24;
        }
        s->theta_q24[ECU_LAM] = lam;
        s->theta_ext[ECU_LAM] = 0;
    }
}

/* this engine's EGT-limited acceleration line at its present speed (ecu/limiters.py egt_line_v):
 * V_d + (V_f - V_d) (T_lim - T_0) / (T_gas - T_0); updates V_f; 0 with *on clear: no cap */
static int32_t egt_line_v(ecu_t *e, int32_t v_prev, int *on)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t vf = sat32(e, (int64_t)s->egt_vf_q24 +
                              (((int64_t)p->egt_lead_cf_q16 * ((int64_t)v_prev - s->egt_vf_q24)) >> 16));
    int64_t rise_dk = (int64_t)(s->egt_lead_q12 >> 12) - p->egt_zero_fuel_dk;
    int64_t limit_rise_dk = (int64_t)p->egt_limit_dk - p->egt_zero_fuel_dk;
    s->egt_vf_q24 = vf;
    *on = p->egt_zero_fuel_dk != 0 && 4 * rise_dk >= limit_rise_dk && vf > p->pump_dead_q24;
    if (!*on) {
        return 0;
    }
    return sat32(e, (int64_t)p->pump_dead_q24 +
                        div_trunc(e, ((int64_t)vf - p->pump_dead_q24) * limit_rise_dk, rise_dk));
}

/* the speed control's voltage under the EGT limit loop and the EGT line (owner set) */
static int32_t egt_limits(ecu_t *e, int32_t v_prev, int32_t v_speed, int32_t egt_err_q24,
                          int egt_ok, int32_t *owner)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t v = v_speed, err, v_loop;
    *owner = ECU_OWNER_SPEED;
    if (egt_ok) {
        err = egt_err_q24;
        if (err < p->egt_engage_q24) {
            v_loop = limit_loop(e, v_prev, err, s->egt_e_prev_q24, p->egt_kp_q24, p->egt_ki_dt_q24,
                                s->owner == ECU_OWNER_EGT);
            if (v_loop < v) {
                v = v_loop;
                *owner = ECU_OWNER_EGT;
            }
        }
        s->egt_e_prev_q24 = err;
    }
    if (p->fuel_schedules_on) {
        int on;
        v_loop = egt_line_v(e, v_prev, &on);
        if (egt_ok && on && v_loop < v) {
            v = v_loop;
            *owner = ECU_OWNER_EGT;
        }
    }
    return v;
}

/* v under the acceleration rate loop, the overspeed loop and the acceleration line (owner
 * and by_line, 1 if the line owns, set) */
static int32_t accel_limits(ecu_t *e, int32_t v_prev, int32_t v, int32_t *owner, int32_t n_q24,
                            int32_t rate_q24, int32_t *by_line)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t err, v_loop, ndot_max = p->accel_max_q24;
    int rate_owned = s->owner == ECU_OWNER_ACCEL && !s->line_owns; /* the rate loop, not the line */
    *by_line = 0;
    if (p->fuel_schedules_on) { /* the acceleration schedule, under the overall limit */
        int32_t sched = schedule_at(e, p->accel_rate_q24, n_q24);
        ndot_max = sched < ndot_max ? sched : ndot_max;
    }
    err = sat32(e, (int64_t)ndot_max - rate_q24);
    if (err < p->rate_engage_q24) {
        v_loop = limit_loop(e, v_prev, err, s->acc_e_prev_q24, p->rate_kp_q24, p->rate_ki_dt_q24,
                            rate_owned);
        if (v_loop < v) {
            v = v_loop;
            *owner = ECU_OWNER_ACCEL;
        }
    }
    s->acc_e_prev_q24 = err;
    err = sat32(e, (int64_t)p->n_limit_q24 - n_q24);
    if (err < p->n_limit_engage_q24) {
        v_loop = limit_loop(e, v_prev, err, s->nlim_e_prev_q24, p->n_limit_kp_q24,
                            p->n_limit_ki_dt_q24, s->owner == ECU_OWNER_NLIMIT);
        if (v_loop < v) {
            v = v_loop;
            *owner = ECU_OWNER_NLIMIT;
        }
    }
    s->nlim_e_prev_q24 = err;
    if (p->fuel_schedules_on) {
        /* the line's fuel with the pump as estimated, within schedule_pump_range (the estimator
         * learns the pump while the line holds it: a weak pump's line rises) */
        v_loop = schedule_v(e, p->accel_line_q24, n_q24, p->sched_lam_lo_q24, p->sched_lam_hi_q24);
        if (v_loop < v) {
            v = v_loop;
            *owner = ECU_OWNER_ACCEL;
            *by_line = 1;
        }
    }
    return v;
}

/* v over the deceleration rate loop and the deceleration floor (owner set) */
static int32_t decel_limits(ecu_t *e, int32_t v_prev, int32_t v, int32_t *owner, int32_t n_q24,
                            int32_t rate_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t v_loop, err = sat32(e, (int64_t)rate_q24 + p->decel_max_q24); /* margin above it */
    if (err < p->rate_engage_q24) {
        v_loop = limit_loop(e, v_prev, -(int64_t)err, -(int64_t)s->dec_e_prev_q24, p->rate_kp_q24,
                            p->rate_ki_dt_q24, s->owner == ECU_OWNER_DECEL);
        if (v_loop > v) {
            v = v_loop;
            *owner = ECU_OWNER_DECEL;
        }
    }
    s->dec_e_prev_q24 = err;
    if (p->fuel_schedules_on) {
        /* one-sided: a weaker pump raises the floor, an estimate over Lambda_c never lowers it */
        v_loop = schedule_v(e, p->decel_floor_q24, n_q24, p->sched_lam_lo_q24, p->lambda_comm_q24);
        if (v_loop > v) {
            v = v_loop;
            *owner = ECU_OWNER_DECEL;
        }
    }
    return v;
}

/* min/max selection, voltage limits and slew; sets owner, v_saturated, line_owns (the
 * acceleration line, not its rate loop, owns) and v_applied_q24 */
static int32_t select_voltage(ecu_t *e, int32_t v_speed, int32_t egt_err_q24, int egt_ok,
                              int32_t n_q24, int32_t rate_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t v_prev, v, owner, v_lim, by_line;
    if (!p->limiters_on) {
        s->owner = ECU_OWNER_SPEED;
        s->v_saturated = 0;
        s->line_owns = 0;
        s->v_applied_q24 = v_speed;
        return v_speed;
    }
    v_prev = s->v_applied_q24;
    v = egt_limits(e, v_prev, v_speed, egt_err_q24, egt_ok, &owner);
    v = accel_limits(e, v_prev, v, &owner, n_q24, rate_q24, &by_line);
    v = decel_limits(e, v_prev, v, &owner, n_q24, rate_q24);
    v_lim = (int32_t)clamp(v, p->v_min_q24, p->v_max_q24);
    s->v_saturated = v_lim != v ? 1 : 0;
    v_lim = (int32_t)clamp(v_lim, (int64_t)v_prev - p->v_slew_q24, (int64_t)v_prev + p->v_slew_q24);
    s->owner = owner;
    s->line_owns = owner == ECU_OWNER_ACCEL ? by_line : 0;
    s->v_applied_q24 = v_lim;
    return v_lim;
}

static void reset_loops(ecu_state_t *s, int32_t v_q24)
{
    s->v_applied_q24 = v_q24;
    s->line_owns = 0;
    s->egt_e_prev_q24 = 0;
    s->egt_vf_q24 = v_q24;
    s->acc_e_prev_q24 = 0;
    s->dec_e_prev_q24 = 0;
    s->nlim_e_prev_q24 = 0;
    s->owner = ECU_OWNER_SPEED;
    s->v_saturated = 0;
}

/* ---- ecu/fast_model.py (eq. 3.5 as an observer) ------------------------------------------- */

/* the input's acceleration (Lambda + Th1 dN + Th2 dN^2) dV, %N/s^2 in Q15.16, not saturated */
ECU_INLINE int64_t input_accel_q16(const int32_t *th, int32_t n, int32_t u)
{
    int64_t th2_n = ((int64_t)th[ECU_TH2] * n) >> 24;
    return (((int64_t)th[ECU_LAM] * u) >> 32) +
           mul_wide_shr(((int64_t)th[ECU_TH1] * n) >> 24, u, 32) +
           mul_wide_shr(mul_wide_shr(th2_n, n, 24), u, 32);
}

static void observer_step(ecu_t *e, int32_t u, int32_t dn_meas, int valid)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    const int32_t *th = s->theta_q24;
    int32_t n = s->obs_n_q24;
    int32_t v = s->obs_v_q24;
    int64_t innov = valid ? sat32(e, (int64_t)dn_meas - n) : 0;
    int32_t acc_q16 = sat32(e, (((int64_t)th[ECU_AP21] * n) >> 32) +
                                   (((int64_t)th[ECU_AP22] * v) >> 32) + input_accel_q16(th, n, u) +
                                   (((int64_t)pump_bias_q16(e) *
                                     fuel_shape_q24(e, n, ((int64_t)n * n) >> 32)) >> 24));
    s->obs_n_q24 = sat32(e, (int64_t)n + (((int64_t)p->dt_q24 * v) >> 24) +
                                ((p->obs_l1_dt_q24 * innov) >> 24));
    s->obs_v_q24 = sat32(e, (int64_t)v + (((int64_t)p->dt_q24 * acc_q16) >> 16) +
                                ((p->obs_l2_dt_q24 * innov) >> 24));
}

/* ---- ecu/rate_filter.py (the control laws' speed rate) ------------------------------------- */

static void rate_filter_start(ecu_state_t *s, int32_t dn)
{
    s->rf_n_q24 = dn;
    s->rf_v_q24 = 0;
    s->rf_a_q16 = 0;
}

static void rate_filter_step(ecu_t *e, int32_t dn, int32_t u, int valid)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t n = s->rf_n_q24;
    int32_t v = s->rf_v_q24;
    int32_t a = s->rf_a_q16;
    int64_t err = valid ? sat32(e, (int64_t)dn - n) : 0;
    int32_t acc_q16 = sat32(e, (int64_t)a + input_accel_q16(s->theta_q24, n, u));
    s->rf_n_q24 = sat32(e, (int64_t)n + (((int64_t)p->dt_q24 * v) >> 24) +
                               ((p->rf_k1_q24 * err) >> 24));
    s->rf_v_q24 = sat32(e, (int64_t)v + (((int64_t)p->dt_q24 * acc_q16) >> 16) +
                               ((p->rf_k2_q24 * err) >> 24));
    s->rf_a_q16 = sat32(e, (int64_t)a + ((p->rf_k3_q24 * err) >> 32));
}

/* ---- ecu/modes.py -------------------------------------------------------------------------- */

static int32_t next_mode(int32_t mode, int arm, int stop, int running, int demand_fresh,
                         int trip_fault, int trip_shutdown, int spooled_down, int fuelled,
                         int relight, int cooled, int ready)
{
    if (mode == ECU_FAULT) {
        return ECU_FAULT;
    }
    if (trip_fault && (mode == ECU_ARMED || mode == ECU_RUN)) {
        return ECU_FAULT;
    }
    if (mode == ECU_OFF) {
        if (!arm || stop || !ready) {
            return ECU_OFF;
        }
        return running && demand_fresh ? ECU_RUN : ECU_ARMED;
    }
    if (mode == ECU_ARMED) {
        if (stop || !arm || trip_shutdown) {
            return fuelled ? ECU_SHUTDOWN : ECU_OFF;
        }
        return running && demand_fresh ? ECU_RUN : ECU_ARMED;
    }
    if (mode == ECU_RUN) {
        if (relight && arm && !stop) {
            return ECU_ARMED;
        }
        return trip_shutdown || stop || !arm ? ECU_SHUTDOWN : ECU_RUN;
    }
    return spooled_down && cooled && !arm ? ECU_OFF : ECU_SHUTDOWN;
}

/* ---- ecu/start_sequencer.py ---------------------------------------------------------------- */

/* The sequencer's commands of the tick (Python: the SeqOut record) are the state's
 * starter_cpct and igniter words, which the tick clears before the sequencer runs; its pump
 * voltage is s->seq_v_q24. */

static int32_t seq_timer_step(int32_t t)
{
    return t < INT32_MAX ? t + 1 : INT32_MAX;
}

static void seq_enter(ecu_state_t *s, int32_t state)
{
    s->seq_state = state;
    s->seq_timer = 0;
}

/* floor(sqrt(x)), bit by bit, for x < 2^62 (the result fits an int32). The loop is bounded:
 * `bit` starts at 2^62 and drops by a factor of 4 in every pass of either loop, so the two
 * loops together run at most 32 passes (31 + 1); the tick calls it only at a start from rest
 * (take_egt_at_rest). */
ECU_INLINE uint32_t isqrt_u64(uint64_t x)
{
    uint64_t r = 0;
    uint64_t bit = (uint64_t)1 << 62;
    while (bit > x) {
        bit >>= 2;
    }
    while (bit != 0) {
        if (x >= r + bit) {
            x -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    return (uint32_t)r;
}

/* take_egt_at_rest: at a start from rest, the EGT read now as the day's temperature, if in
 * range: 1 / sqrt(theta) in Q24 for corrected speed, and the start's EGT target (the same
 * corrected temperature, under the cap) */
ECU_INLINE void take_egt_at_rest(ecu_t *e)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    if (p->inlet_from_egt && s->egt_dk >= ECU_INLET_MIN_DK && s->egt_dk <= ECU_INLET_MAX_DK) {
        /* inlet_ck in 22300..33300 (0.01 K): no overflow and no division by zero; the shift
         * and the root's range are checked at compile time (top of this file) */
        int32_t inlet_ck = s->egt_dk * 10;
        int64_t target = (int64_t)p->seq_egt_target_dk * inlet_ck;
        target = target < 0 ? -(int64_t)udiv64_32((uint64_t)-target, ECU_T_STD_CK)
                            : (int64_t)udiv64_32((uint64_t)target, ECU_T_STD_CK);
        s->ncor_k_q24 =
            (int32_t)isqrt_u64(udiv64_32((uint64_t)ECU_T_STD_CK << 48, (uint32_t)inlet_ck));
        s->seq_target_dk = (int32_t)(target < p->seq_egt_cap_dk ? target : p->seq_egt_cap_dk);
    }
}

/* start_begin: a start (SPIN_UP) or, for a relight, the ignition with the engine still turning */
static void start_begin(ecu_state_t *s, int relight)
{
    s->seq_reason = ECU_ABORT_NONE;
    s->seq_v_q24 = 0;
    if (relight) {
        s->seq_egt_ref_q8 = (int32_t)((int64_t)s->egt_dk * 256);
        seq_enter(s, ECU_SEQ_IGNITION);
    } else {
        seq_enter(s, ECU_SEQ_SPIN_UP);
    }
}

/* _fuel_ramp: down by ramp_v_step over the start's EGT target on the day, else up by it while the shaft
 * accelerates slower than accel_q24 (held while faster), within [ign_v0, min(v_cap, v_max)] */
static void fuel_ramp(ecu_t *e, int32_t egt_dk, int32_t rate_q24, int32_t v_cap_q24)
{
    const ecu_params_t *p = e->p;
    int64_t step = 0;
    if (egt_dk >= e->s.seq_target_dk) {
        step = -(int64_t)p->seq_ramp_v_step_q24;
    } else if (rate_q24 < p->seq_accel_q24) {
        step = p->seq_ramp_v_step_q24;
    }
    e->s.seq_v_q24 = (int32_t)clamp(e->s.seq_v_q24 + step, p->seq_ign_v0_q24,
                                    v_cap_q24 < p->v_max_q24 ? v_cap_q24 : p->v_max_q24);
}

/* start_step: one tick of the start in ARMED at speed n_rpm, EGT egt_dk and speed rate rate_q24
 * (%N/s, Q7.24); returns an abort reason (ECU_ABORT_NONE while starting); s->seq_state is
 * ECU_SEQ_RUN once the engine is at idle */
static int32_t start_step(ecu_t *e, int32_t n_rpm, int32_t egt_dk, int32_t rate_q24,
                          int32_t v_cap_q24)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t state = s->seq_state;
    int32_t t = seq_timer_step(s->seq_timer);
    int32_t abort = ECU_ABORT_NONE;
    s->seq_timer = t;
    if (state == ECU_SEQ_SPIN_UP) {
        s->starter_cpct = p->seq_start_cpct;
        s->igniter = 1;
        if (t >= p->seq_purge_ticks && n_rpm >= p->seq_ign_rpm) {
            s->seq_egt_ref_q8 = (int32_t)((int64_t)egt_dk * 256);
            s->seq_v_q24 = p->seq_ign_v0_q24;
            seq_enter(s, ECU_SEQ_IGNITION);
        } else if (t >= p->seq_spinup_ticks) {
            abort = ECU_ABORT_STARTER_FAILURE;
        }
    } else if (state == ECU_SEQ_IGNITION) {
        s->starter_cpct = p->seq_start_cpct;
        s->igniter = 1;
        if (s->seq_v_q24 < p->seq_ign_v0_q24) {
            s->seq_v_q24 = p->seq_ign_v0_q24;
        } else {
            int64_t v = (int64_t)s->seq_v_q24 + p->seq_ign_v_step_q24;
            s->seq_v_q24 = v < p->seq_ign_v_max_q24 ? (int32_t)v : p->seq_ign_v_max_q24;
        }
        { /* the light-off reference: follows the EGT down at once, up at most light_track */
            int64_t x_q8 = (int64_t)egt_dk * 256;
            int64_t ref = (int64_t)s->seq_egt_ref_q8 + p->seq_light_track_q8;
            s->seq_egt_ref_q8 = (int32_t)(x_q8 < ref ? x_q8 : ref);
        }
        if (egt_dk >= (int64_t)(s->seq_egt_ref_q8 >> 8) + p->seq_light_rise_dk) {
            seq_enter(s, ECU_SEQ_RAMP);
        } else if (t >= p->seq_ign_ticks) {
            abort = ECU_ABORT_IGNITION_TIMEOUT;
        }
    } else if (state == ECU_SEQ_RAMP || state == ECU_SEQ_STABILISE) {
        fuel_ramp(e, egt_dk, rate_q24, v_cap_q24); /* (Python: in each of the two branches) */
        if (state == ECU_SEQ_RAMP) {
            int64_t duty = p->seq_start_cpct + (int64_t)t * p->seq_starter_step_cpct;
            s->starter_cpct = duty < ECU_DUTY_FULL_CPCT ? (int32_t)duty : ECU_DUTY_FULL_CPCT;
            s->igniter = t < p->seq_igniter_hold_ticks;
            if (n_rpm >= p->seq_cutoff_rpm) {
                seq_enter(s, ECU_SEQ_STABILISE);
            } else if (t >= p->seq_ramp_ticks) {
                abort = ECU_ABORT_SLOW_ACCEL;
            } else if (t >= p->seq_igniter_hold_ticks &&
                       egt_dk < (int64_t)(s->seq_egt_ref_q8 >> 8) + (p->seq_light_rise_dk >> 1)) {
                abort = ECU_ABORT_FLAMEOUT;
            }
        } else if (n_rpm >= p->seq_idle_rpm) {
            seq_enter(s, ECU_SEQ_RUN);
        } else if (t >= p->seq_stabilise_ticks || n_rpm < p->seq_ign_rpm) {
            abort = ECU_ABORT_SLOW_ACCEL;
        }
    }
    if (abort == ECU_ABORT_NONE && egt_dk > p->seq_hot_dk) {
        abort = ECU_ABORT_HOT_START;
    }
    if (abort != ECU_ABORT_NONE) {
        s->seq_reason = abort;
        s->starter_cpct = 0;
        s->igniter = 0;
        s->seq_v_q24 = 0;
    }
    return abort;
}

/* cooled: the stop is over, DONE and held for soak_ticks without the EGT soaking back */
static int cooled(const ecu_t *e)
{
    return e->s.seq_state == ECU_SEQ_DONE && e->s.seq_timer >= e->p->seq_soak_ticks;
}

/* stop_step: one tick of the stop in SHUTDOWN (fuel cut): spool down, cool down with the
 * starter once the rotor is slow enough for its clutch, DONE when cool (back to COOL_DOWN if the
 * heat soaks back by more than cool_rearm_dk) */
static void stop_step(ecu_t *e, int32_t n_rpm, int32_t egt_dk)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t state = s->seq_state;
    int hot = egt_dk > p->seq_cool_egt_dk;
    s->seq_timer = seq_timer_step(s->seq_timer);
    s->starter_cpct = 0;
    s->igniter = 0;
    s->seq_v_q24 = 0;
    if (state != ECU_SEQ_SPOOL_DOWN && state != ECU_SEQ_COOL_DOWN && state != ECU_SEQ_DONE) {
        seq_enter(s, ECU_SEQ_SPOOL_DOWN);
        state = ECU_SEQ_SPOOL_DOWN;
    }
    if (state == ECU_SEQ_SPOOL_DOWN) {
        if (n_rpm <= p->seq_cool_rpm) {
            seq_enter(s, hot ? ECU_SEQ_COOL_DOWN : ECU_SEQ_DONE);
        }
    } else if (state == ECU_SEQ_COOL_DOWN) {
        if (!hot) {
            seq_enter(s, ECU_SEQ_DONE);
        } else if (s->seq_timer >= p->seq_cool_ticks) { /* given up: no re-arm */
            seq_enter(s, ECU_SEQ_DONE);
            s->seq_timer = p->seq_soak_ticks;
        }
    } else if (s->seq_timer < p->seq_soak_ticks &&
               egt_dk > (int64_t)p->seq_cool_egt_dk + p->seq_cool_rearm_dk &&
               n_rpm <= p->seq_cool_rpm) {
        seq_enter(s, ECU_SEQ_COOL_DOWN); /* the metal's heat soaked back: cool again */
    }
    if (s->seq_state == ECU_SEQ_COOL_DOWN) {
        s->starter_cpct = p->seq_cool_cpct;
    }
}

/* ---- ecu/firmware.py ----------------------------------------------------------------------- */

static int32_t ring(int32_t idx) /* (idx + RATE_BUF_LEN) % RATE_BUF_LEN for -LEN < idx < LEN */
{
    return idx < 0 ? idx + ECU_RATE_BUF_LEN : idx;
}

/* central difference of speed at the sample `age` ticks old, %N/s (Q7.24) */
static int32_t rate_q24(ecu_t *e, int32_t age)
{
    const ecu_params_t *p = e->p;
    const ecu_state_t *s = &e->s;
    int32_t m = p->rate_half_window;
    int64_t d_rpm = (int64_t)s->n_hist_rpm[ring(s->hist_idx - age + m)] -
                    s->n_hist_rpm[ring(s->hist_idx - age - m)];
    return div_trunc(e, mul_wide_shr(d_rpm * p->rpm_to_q24_k, p->rate_hz, 16), 2 * (int64_t)m);
}

ECU_INLINE int32_t dn_q24(ecu_t *e, int32_t age)
{
    const ecu_state_t *s = &e->s;
    int64_t rpm = s->n_hist_rpm[ring(s->hist_idx - age)];
    return sat32(e, ((rpm * e->p->rpm_to_q24_k) >> 16) - e->p->trim_n_q24);
}

static int32_t q24_to_cpct(int64_t x_q24)
{
    return (int32_t)((x_q24 * 100 + (1 << 23)) >> 24);
}

static int32_t age(int32_t a)
{
    return a < ECU_AGE_MAX ? a + 1 : ECU_AGE_MAX;
}

void ecu_init(ecu_t *e, const ecu_params_t *p)
{
    int k;
    memset(&e->s, 0, sizeof e->s); /* every field an int32: all bits zero is 0 */
    memset(&e->o, 0, sizeof e->o);
    e->p = p;
    for (k = 0; k < ECU_N_THETA; k++) {
        e->s.theta_q24[k] = p->init_theta_q24[k];
    }
    e->s.supply_mv = p->supply_nominal_mv;
    e->s.demand_q24 = p->idle_q24;
    e->s.mode = ECU_OFF;
    e->s.ncor_k_q24 = p->ncor_k_q24; /* the operator's day (ecu/inlet.py) */
    e->s.seq_target_dk = p->seq_day_target_dk;
    e->sat_pending = 0;
    e->rate_q24 = 0;
}

/* ---- one tick, in stages (ecu/firmware.py Ecu.tick: the same stages in the same order) ------ */

/* What one tick's stages hand each other (ecu/firmware.py TickVars), on the tick's stack. */
typedef struct {
    int32_t mode, new_mode, faults;
    int32_t n_rpm, n_q24, dn, rate, ctrl_rate, demand;
    int32_t start_abort, seq_v, u, v, pump_mv, duty, enable;
    int speed_ok, egt_ok, analog_fresh, inputs_valid;
    int running, trip_fault, trip_shutdown, relight;
} tick_vars_t;

/* the frames since the last tick: speed and EGT (checked; speed substituted by the observer
   once failed), supply and pump current, demand (held, then idle) */
static void stage_sensors(ecu_t *e, const ecu_inputs_t *in, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t demand;
    if (in->sensor_status == ECU_E2E_OK) {
        s->sensor_age = 0;
        if (s->speed_seen) {
            t->faults |= speed_checks(e, in->speed_rpm, s->speed_rpm, s->v_applied_q24);
        }
        s->speed_rpm = in->speed_rpm;
        egt_lead_step(e, in->egt_dk);
        s->egt_dk = in->egt_dk;
        t->faults |= egt_open_check(e, in->egt_dk);
        s->inputs_seen |= valid_readings(p, in->speed_rpm, in->egt_dk);
    } else {
        s->sensor_age = age(s->sensor_age);
        t->faults |= ECU_FAULT_SENSOR_FRAME_LOST;
    }
    if (t->faults & (ECU_FAULT_SPEED_RANGE | ECU_FAULT_SPEED_RATE | ECU_FAULT_SPEED_STUCK)) {
        s->speed_failed = 1;
    }
    t->speed_ok = s->speed_failed == 0 && s->sensor_age == 0;
    t->inputs_valid = s->inputs_seen == ECU_SEEN_ALL;
    if (t->speed_ok) {
        t->n_rpm = s->speed_rpm;
    } else if (!(s->inputs_seen & ECU_SEEN_SPEED)) {
        t->n_rpm = 0; /* no reading since power-up: nothing to substitute (not the trim speed) */
    } else {
        t->n_rpm = (int32_t)((((int64_t)s->obs_n_q24 + p->trim_n_q24) * ECU_RPM_PER_PCT + (1 << 23))
                             >> 24);
        if (s->speed_failed) {
            t->faults |= ECU_FAULT_SPEED_SUBSTITUTED;
        }
    }
    t->egt_ok = (t->faults & ECU_FAULT_EGT_OPEN) == 0;

    /* analog frame: supply voltage and pump current */
    t->analog_fresh = in->analog_status == ECU_E2E_OK;
    if (t->analog_fresh) {
        s->analog_age = 0;
        s->supply_mv = in->supply_mv;
        s->pump_ma = in->pump_ma;
    } else {
        s->analog_age = age(s->analog_age);
        if (s->analog_age > p->analog_loss_ticks) {
            s->supply_mv = p->supply_nominal_mv;
            t->faults |= ECU_FAULT_ANALOG_FRAME_LOST;
        }
    }

    /* demand frame: hold, then idle, shut down later */
    if (in->demand_status == ECU_E2E_OK) {
        s->demand_age = 0;
        s->demand_q24 = (int32_t)clamp(div_trunc(e, (int64_t)in->demand_cpct * ONE_Q24, 100),
                                       p->idle_q24, p->demand_max_q24);
        s->open_loop_q24 = div_trunc(e, (int64_t)in->open_loop_mv * ONE_Q24, 1000);
        s->arm = in->arm ? 1 : 0;
        s->stop = in->stop ? 1 : 0;
    } else {
        s->demand_age = age(s->demand_age);
    }
    demand = s->demand_q24;
    if (s->demand_age > p->demand_hold_ticks) {
        demand = p->idle_q24;
        t->faults |= ECU_FAULT_DEMAND_LOST;
    }
    if (!t->egt_ok && demand > p->egt_fail_demand_q24) {
        demand = p->egt_fail_demand_q24;
    }
    t->demand = demand;
}

/* the speed history (raw rpm) and what it gives: speed deviation, the central-difference rate
   (the observer's while the sensor is out) and the filtered rate */
static void stage_history(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t m = p->rate_half_window;
    s->hist_idx = (s->hist_idx + 1) % ECU_RATE_BUF_LEN;
    s->n_hist_rpm[s->hist_idx] = t->n_rpm;
    s->u_hist_q24[s->hist_idx] = 0;
    if (s->speed_seen < ECU_RATE_BUF_LEN) {
        s->speed_seen++;
    }
    t->n_q24 = sat32(e, ((int64_t)t->n_rpm * p->rpm_to_q24_k) >> 16);
    t->dn = sat32(e, (int64_t)t->n_q24 - p->trim_n_q24);
    if (!t->speed_ok) {
        t->rate = s->obs_v_q24;
    } else if (s->speed_seen > 2 * m) {
        t->rate = rate_q24(e, m);
    } else {
        t->rate = 0;
    }
    if (s->speed_seen == 1) {
        rate_filter_start(s, t->dn);
    } else { /* with the voltage applied over the last tick (0 outside RUN) */
        rate_filter_step(e, t->dn, s->u_hist_q24[ring(s->hist_idx - 1)], t->speed_ok);
    }
    /* the control laws' and limit loops' rate: filtered while the sensor is valid */
    t->ctrl_rate = p->rate_filter_on && t->speed_ok ? s->rf_v_q24 : t->rate;
}

/* protection trips: overspeed, flameout, EGT over its maximum, pump current, sensor frames
   lost; which of them end in FAULT, which in SHUTDOWN (or a relight) */
static void stage_trips(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int running = t->mode == ECU_ARMED || t->mode == ECU_RUN;
    int flameout = 0;
    s->overspeed_cnt = persist(s->overspeed_cnt, running && t->n_rpm > p->overspeed_rpm,
                               p->overspeed_ticks);
    if (s->overspeed_cnt >= p->overspeed_ticks) {
        t->faults |= ECU_FAULT_OVERSPEED;
    }
    s->flameout_cnt = persist(s->flameout_cnt, t->mode == ECU_RUN && t->n_rpm < p->flameout_rpm,
                              p->flameout_ticks);
    s->flame_egt_cnt = persist(s->flame_egt_cnt,
                               t->mode == ECU_RUN && t->egt_ok && s->egt_dk < p->flameout_egt_dk,
                               p->flameout_egt_ticks);
    if (s->flameout_cnt >= p->flameout_ticks || s->flame_egt_cnt >= p->flameout_egt_ticks) {
        t->faults |= ECU_FAULT_FLAMEOUT;
        flameout = 1;
    }
    s->egt_over_cnt = persist(s->egt_over_cnt, running && t->egt_ok && s->egt_dk > p->egt_max_dk,
                              p->egt_max_ticks);
    if (s->egt_over_cnt >= p->egt_max_ticks) {
        t->faults |= ECU_FAULT_EGT_OVERTEMP;
    }
    if (t->mode == ECU_RUN && t->analog_fresh) {
        t->faults |= pump_current_checks(e, s->pump_ma, s->v_applied_q24);
    }
    t->trip_fault = (t->faults & ECU_FAULT_TRIP) != 0 ||
                    (running && s->sensor_age > p->sensor_loss_ticks);
    t->trip_shutdown = flameout || s->demand_age >= p->demand_shutdown_ticks;
    t->relight = flameout && p->start_on && s->relights < p->seq_relight_max;
}

/* in ARMED, the start sequencer's step: this tick's starter, igniter and pump, or an abort;
   whether the engine runs (by the sequencer, else by the speed alone) */
static void stage_start_sequencer(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    s->starter_cpct = 0;
    s->igniter = 0;
    t->seq_v = 0;
    t->start_abort = ECU_ABORT_NONE;
    t->running = t->n_rpm >= p->run_entry_rpm;
    if (t->mode == ECU_ARMED && p->start_on) {
        int32_t v_cap = p->v_max_q24;
        if (p->fuel_schedules_on) { /* under the acceleration line of the weakest pump the
                                       schedules accept (no pump estimate yet in a start) */
            v_cap = schedule_v(e, p->accel_line_q24, t->n_q24, p->sched_lam_lo_q24,
                               p->sched_lam_lo_q24);
        }
        t->start_abort = start_step(e, t->n_rpm, s->egt_dk, t->ctrl_rate, v_cap);
        t->seq_v = s->seq_v_q24;
        t->running = s->seq_state == ECU_SEQ_RUN;
        if ((s->stop || !s->arm || t->trip_shutdown) && !t->start_abort) {
            s->seq_reason = ECU_ABORT_STOPPED;
        }
    }
}

/* entry into RUN: bumpless at the entry voltage (where the start left the pump), the loops,
   integrators and models started where the engine is */
static void enter_run(ecu_t *e, const tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t v_entry = p->entry_v_q24;
    if (t->mode == ECU_ARMED && p->start_on) {
        v_entry = s->seq_v_q24; /* where the start left the pump */
        if (p->fuel_schedules_on && p->pump_scaling_on) {
            pump_from_start(e, t->n_q24, v_entry);
        }
    }
    s->seq_state = ECU_SEQ_RUN;
    reset_loops(s, v_entry);
    s->hist_fill = 0;
    s->theta_q24[ECU_PID_I] = sat32(e, (int64_t)v_entry - p->trim_v_q24);
    s->theta_ext[ECU_PID_I] = 0;
    s->u_lag_q24 = s->theta_q24[ECU_PID_I];
    s->xm1_q24 = t->dn;
    s->xm2_q24 = 0;
    s->obs_n_q24 = t->dn;
    s->obs_v_q24 = t->rate;
    s->xh1_q24 = t->dn; /* the identification model starts where the engine is */
    s->xh2_q24 = t->rate;
}

/* the mode for this tick (ecu/modes.py) and what its transitions start: a start or a relight,
   the entry into RUN, the wait for a re-arm */
static void stage_mode(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t mode = t->mode, new_mode;
    int demand_fresh = s->demand_age <= p->demand_hold_ticks;
    if (!s->arm) {
        s->rearm_wait = 0;
    }
    new_mode = next_mode(mode, s->arm, s->stop, t->running, demand_fresh, t->trip_fault,
                         t->trip_shutdown || t->start_abort, t->n_rpm < p->shutdown_done_rpm,
                         t->start_abort || s->seq_state >= ECU_SEQ_IGNITION, t->relight,
                         cooled(e) || !p->start_on,
                         t->inputs_valid && demand_fresh && !s->rearm_wait);
    if ((mode == ECU_ARMED || mode == ECU_RUN) && new_mode != ECU_ARMED && new_mode != ECU_RUN) {
        s->rearm_wait = s->arm; /* a start is never retried by itself: the arm must drop first */
    }
    if (new_mode == ECU_ARMED && mode != ECU_ARMED && p->start_on) { /* a start or a relight */
        if (mode == ECU_RUN) {
            s->relights++;
            s->flameout_cnt = 0;
            s->flame_egt_cnt = 0;
        } else {
            s->relights = 0;
        }
        start_begin(s, mode == ECU_RUN);
        if (mode != ECU_RUN) {
            take_egt_at_rest(e);
        }
    }
    if (new_mode == ECU_OFF) {
        s->seq_state = ECU_SEQ_OFF;
    }
    if (new_mode == ECU_RUN && mode != ECU_RUN) {
        enter_run(e, t);
    }
    s->mode = new_mode;
    t->new_mode = new_mode;
}

/* in RUN: the estimator (eq. 4.7/4.31), the speed controller (MRAC eq. 5.4/5.16, PID,
   scheduled PI or open loop) and the reference model (eq. 5.18-5.19) */
static void stage_control_law(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t m = p->rate_half_window;
    int32_t r;
    int adapt = t->speed_ok;
    /* under the acceleration line the estimator learns the pump the line needs, from a
       reading that answers the pump (not one that stays put while the pump moves: a stuck
       sensor, before its fault trips, would teach a weak pump and raise the line) */
    int line_learns = s->line_owns && s->speed_stuck_cnt == 0;
    if (s->hist_fill < ECU_RATE_BUF_LEN) {
        s->hist_fill++;
    }
    if (p->freeze_on && (s->v_saturated || (s->owner != ECU_OWNER_SPEED && !line_learns))) {
        adapt = 0;
    }
    if (p->adapt_band_q24 && (t->dn > p->adapt_band_q24 || t->dn < -p->adapt_band_q24)) {
        adapt = 0; /* off the trim speed the fast model no longer holds */
    }
    if (t->speed_ok && s->hist_fill > m + 1 && s->speed_seen > 2 * m + 1) {
        /* the rate at age m: the history stage's (the same samples, the sensor valid) */
        estimator_step(e, dn_q24(e, m + 1), rate_q24(e, m + 1), dn_q24(e, m), t->rate,
                       s->u_hist_q24[ring(s->hist_idx - m - 1)], adapt);
    }
    r = sat32(e, (int64_t)t->demand - p->trim_n_q24);
    if (p->controller == ECU_CTRL_MRAC) {
        t->u = command_lag(e, mrac_control(e, t->dn, t->ctrl_rate, r));
        mrac_gain_update(e);
    } else if (p->controller == ECU_CTRL_PID) {
        t->u = pid_control(e, sat32(e, (int64_t)t->demand - t->n_q24), t->ctrl_rate);
    } else if (p->controller == ECU_CTRL_PI) {
        t->u = pi_control(e, sat32(e, (int64_t)t->demand - t->n_q24), t->n_q24);
    } else {
        t->u = sat32(e, (int64_t)s->open_loop_q24 - p->trim_v_q24);
    }
    reference_model_step(e, r);
}

/* in RUN: the EGT error (the hotter of the probe and the gas), the min/max selection of the
   speed command with the limit loops and fuel schedules, integrator tracking of the loops
   that did not win, and the observer (eq. 3.5) on the applied voltage */
static void stage_limit_selection(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t e_dk, room_dk, u_applied;
    int64_t probe_dk, gas_dk;
    /* the hotter of the probe and the gas (the lead) against the limit; the gas may pass it by
       what the probe still reads under it, up to the transient allowance */
    probe_dk = p->egt_limit_dk - s->egt_dk;
    room_dk = (int32_t)clamp(probe_dk, 0, p->egt_gas_margin_dk);
    gas_dk = (int64_t)p->egt_limit_dk + room_dk - (s->egt_lead_q12 >> 12);
    e_dk = (int32_t)clamp(gas_dk < probe_dk ? gas_dk : probe_dk, -ECU_EGT_ERROR_MAX_DK,
                          ECU_EGT_ERROR_MAX_DK);
    t->v = select_voltage(e, sat32(e, (int64_t)p->trim_v_q24 + t->u),
                          div_trunc(e, (int64_t)e_dk * ONE_Q24, 10), t->egt_ok, t->n_q24,
                          t->ctrl_rate);
    u_applied = sat32(e, (int64_t)t->v - p->trim_v_q24);
    if (p->controller == ECU_CTRL_PID) {
        pid_track(e, sat32(e, (int64_t)t->demand - t->n_q24), t->ctrl_rate, u_applied);
    } else if (p->controller == ECU_CTRL_PI) {
        pi_track(e, sat32(e, (int64_t)t->demand - t->n_q24), t->n_q24, u_applied);
    }
    if (s->owner != ECU_OWNER_SPEED) { /* the lag tracks what a limit applies (anti-windup) */
        s->u_lag_q24 = u_applied;
    }
    observer_step(e, u_applied, t->dn, t->speed_ok);
    s->u_hist_q24[s->hist_idx] = u_applied;
}

/* the pump's duty from the measured supply, the starter and igniter: in RUN at the selected
   voltage; otherwise the sequencer's (a stop's cool-down, a start) with the models held where
   the engine is */
static void stage_pump_driver(ecu_t *e, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int run = t->new_mode == ECU_RUN;
    if (run) {
        t->pump_mv = volts_q24_to_mv(t->v);
        if (s->owner != ECU_OWNER_SPEED) {
            t->faults |= ECU_FAULT_LIMITER_ACTIVE;
        }
    } else {
        if (t->new_mode == ECU_SHUTDOWN && p->start_on) {
            stop_step(e, t->n_rpm, s->egt_dk);
            t->seq_v = 0;
        } else if (t->new_mode != ECU_ARMED) {
            t->seq_v = 0; /* a start that just ended: no fuel */
        }
        s->v_applied_q24 = t->seq_v;
        s->xm1_q24 = t->dn;
        s->xm2_q24 = 0;
        s->obs_n_q24 = t->dn;
        s->obs_v_q24 = t->rate;
        s->xh1_q24 = t->dn;
        s->xh2_q24 = t->rate;
        t->pump_mv = volts_q24_to_mv(t->seq_v);
    }
    /* in RUN always (enabled, its clipping reported), outside RUN for the start's fuel only */
    t->duty = run || t->pump_mv > 0 ? pump_duty(e, t->pump_mv, s->supply_mv) : 0;
    t->enable = run || t->duty > 0;
    if (run && s->v_saturated) {
        t->faults |= ECU_FAULT_PUMP_SATURATED;
    }
    if (t->new_mode != ECU_ARMED && t->new_mode != ECU_SHUTDOWN) {
        s->starter_cpct = 0;
        s->igniter = 0;
    }
}

/* bench test functions (ecu/actuator_tests.py) */
static int32_t test_level_max(const ecu_params_t *p, int32_t test)
{
    if (test == ECU_TEST_STARTER) {
        return p->seq_start_cpct;
    }
    return test == ECU_TEST_PRIME ? volts_q24_to_mv(p->seq_ign_v_max_q24) : 0;
}

static int test_request_ok(const ecu_params_t *p, int32_t test, int32_t level, int32_t ms)
{
    static const int32_t max_ms[4] = {0, ECU_TEST_MAX_MS_GLOW, ECU_TEST_MAX_MS_STARTER,
                                      ECU_TEST_MAX_MS_PRIME};
    if (test < ECU_TEST_GLOW || test > ECU_TEST_PRIME || ms < 1 || ms > max_ms[test]) {
        return 0;
    }
    return test == ECU_TEST_GLOW || (level >= 1 && level <= test_level_max(p, test));
}

/* start, hold or end the test (allowed: OFF with no arm or stop request); the test that drives
   the outputs this tick (ECU_TEST_NONE: none) */
static int32_t actuator_test_step(ecu_t *e, const ecu_inputs_t *in, int allowed)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int32_t test;
    int fresh = in->test_request != s->test_request_last;
    s->test_request_last = in->test_request;
    if (!allowed || in->test_request == ECU_TEST_NONE) {
        s->test_active = ECU_TEST_NONE;
        s->test_ticks_left = 0;
    } else if (fresh && test_request_ok(p, in->test_request, in->test_level, in->test_ms)) {
        s->test_active = in->test_request;
        s->test_level_held = in->test_level;
        s->test_ticks_left = (in->test_ms * p->rate_hz + 999) / 1000;
    }
    test = s->test_active;
    if (test < ECU_TEST_GLOW || test > ECU_TEST_PRIME || s->test_ticks_left < 1 ||
        s->test_ticks_left > ECU_TEST_MAX_TICKS) {
        test = ECU_TEST_NONE; /* none running (or a state no start leaves: ended) */
        s->test_active = ECU_TEST_NONE;
        s->test_ticks_left = 0;
    } else {
        s->test_ticks_left--;
        if (s->test_ticks_left == 0) {
            s->test_active = ECU_TEST_NONE; /* its time is up: this tick is its last */
        }
    }
    s->test_time_left_ms = s->test_ticks_left * 1000 / p->rate_hz;
    return test;
}

/* in OFF with no arm or stop request, a bench test function: the igniter, the starter at its
   duty or the pump at its voltage, for the test's time */
static void stage_actuator_tests(ecu_t *e, const ecu_inputs_t *in, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    int allowed = t->new_mode == ECU_OFF && !s->arm && !s->stop;
    int32_t test = actuator_test_step(e, in, allowed);
    if (test == ECU_TEST_GLOW) {
        s->igniter = 1;
    } else if (test == ECU_TEST_STARTER) {
        s->starter_cpct =
            (int32_t)clamp(s->test_level_held, 0, test_level_max(p, ECU_TEST_STARTER));
    } else if (test == ECU_TEST_PRIME) {
        t->pump_mv = (int32_t)clamp(s->test_level_held, 0, test_level_max(p, ECU_TEST_PRIME));
        t->duty = pump_duty(e, t->pump_mv, s->supply_mv);
        t->enable = 1;
    }
}

/* pump health, the fault word, the saturation count and the output record */
static void stage_health(ecu_t *e, const ecu_inputs_t *in, tick_vars_t *t)
{
    const ecu_params_t *p = e->p;
    ecu_state_t *s = &e->s;
    ecu_outputs_t *o = &e->o;
    const int32_t *th = s->theta_q24;
    int32_t health = div_trunc(e, (int64_t)th[ECU_LAM] * 1000, p->lambda_comm_q24);
    int64_t pending;
    if (health < p->health_alarm_pm) {
        t->faults |= ECU_FAULT_PUMP_HEALTH;
    }
    s->faults = t->faults;
    pending = e->sat_pending;
    e->sat_pending = 0;
    s->sat_events = sat32(e, s->sat_events + pending);
    o->tick = in->tick;
    o->duty_cpct = t->duty;
    o->pump_mv = t->pump_mv;
    o->pump_enable = t->enable;
    o->mode = t->new_mode;
    o->fault_word = t->faults & ECU_FAULT_WORD_MASK;
    o->sat_events = s->sat_events;
    o->ap21_q24 = th[ECU_AP21];
    o->ap22_q24 = th[ECU_AP22];
    o->lambda_q24 = th[ECU_LAM];
    o->theta21_q24 = th[ECU_TH1];
    o->theta22_q24 = th[ECU_TH2];
    o->kx1_q24 = th[ECU_KX1];
    o->kx2_q24 = th[ECU_KX2];
    o->kr_q24 = th[ECU_KR];
    o->kf1_q24 = th[ECU_KF1];
    o->kf2_q24 = th[ECU_KF2];
    o->pump_health_pm = health;
    o->nref_cpct = q24_to_cpct((int64_t)s->xm1_q24 + p->trim_n_q24);
    o->n_cpct = q24_to_cpct(t->n_q24);
    o->owner = s->owner;
    o->starter_cpct = s->starter_cpct;
    o->igniter = s->igniter;
    o->seq_state = s->seq_state;
    o->seq_reason = s->seq_reason;
    o->inputs_valid = t->inputs_valid;
}

/* the engine's logbook (ecu/logbook.py logbook_step) from this tick's mode transition:
   starts, runs and their time, the last run's highest EGT and speed, the aborts by reason and
   the last shutdown's reason; every counter saturates */
static int32_t log_inc(int32_t x)
{
    return x < INT32_MAX ? x + 1 : INT32_MAX;
}

static int32_t shutdown_reason(int32_t new_mode, int start_abort, int demand_lost,
                               int trip_shutdown)
{
    if (new_mode == ECU_FAULT) {
        return ECU_SD_FAULT;
    }
    if (start_abort) {
        return ECU_SD_START_ABORT;
    }
    if (demand_lost) {
        return ECU_SD_DEMAND_LOST;
    }
    return trip_shutdown ? ECU_SD_FLAMEOUT : ECU_SD_OPERATOR_STOP;
}

static void stage_logbook(ecu_t *e, const tick_vars_t *t)
{
    ecu_state_t *s = &e->s;
    int32_t mode = t->mode, new_mode = t->new_mode;
    if (new_mode == ECU_ARMED && mode == ECU_OFF) {
        s->log_starts = log_inc(s->log_starts);
    }
    if (new_mode == ECU_RUN && !s->log_in_run) {
        s->log_in_run = 1;
        s->log_runs = log_inc(s->log_runs);
        s->log_last_max_egt_dk = 0;
        s->log_last_max_speed_cpct = 0;
    }
    if (s->log_in_run) {
        if (s->egt_dk > s->log_last_max_egt_dk) {
            s->log_last_max_egt_dk = s->egt_dk;
        }
        if (e->o.n_cpct > s->log_last_max_speed_cpct) {
            s->log_last_max_speed_cpct = e->o.n_cpct;
        }
    }
    if (new_mode == ECU_RUN) {
        if (s->log_run_frac_ticks >= e->p->rate_hz - 1) { /* a second is full */
            s->log_run_frac_ticks = 0;
            s->log_run_time_s = log_inc(s->log_run_time_s);
        } else {
            s->log_run_frac_ticks++;
        }
    }
    if ((mode == ECU_ARMED || mode == ECU_RUN) && new_mode != ECU_ARMED && new_mode != ECU_RUN) {
        s->log_in_run = 0;
        if (mode == ECU_ARMED && s->seq_reason > ECU_ABORT_NONE &&
            s->seq_reason <= ECU_LOG_ABORTS) {
            int32_t k = s->seq_reason - 1;
            s->log_aborts[k] = log_inc(s->log_aborts[k]);
        }
        s->log_last_shutdown =
            shutdown_reason(new_mode, t->start_abort != 0,
                            s->demand_age >= e->p->demand_shutdown_ticks, t->trip_shutdown);
    }
}

/* a stage of the tick, followed by the profiling hook in ECU_STAGE_PROFILE builds */
#ifdef ECU_STAGE_PROFILE
#define STAGE(id, call) \
    do { \
        call; \
        ecu_stage_done(id); \
    } while (0)
#else
#define STAGE(id, call) call
#endif

const ecu_outputs_t *ecu_tick(ecu_t *e, const ecu_inputs_t *in)
{
    ecu_state_t *s = &e->s;
    tick_vars_t t = {0};
    s->ticks = s->ticks < INT32_MAX ? s->ticks + 1 : INT32_MAX;
    t.faults = s->faults & ~ECU_FAULT_TRANSIENT;
    t.mode = s->mode;
    STAGE(ECU_STAGE_SENSORS, stage_sensors(e, in, &t));
    STAGE(ECU_STAGE_HISTORY, stage_history(e, &t));
    STAGE(ECU_STAGE_TRIPS, stage_trips(e, &t));
    STAGE(ECU_STAGE_START_SEQUENCER, stage_start_sequencer(e, &t));
    STAGE(ECU_STAGE_MODE, stage_mode(e, &t));
    if (t.new_mode == ECU_RUN) {
        STAGE(ECU_STAGE_CONTROL_LAW, stage_control_law(e, &t));
        STAGE(ECU_STAGE_LIMIT_SELECTION, stage_limit_selection(e, &t));
    }
    STAGE(ECU_STAGE_PUMP_DRIVER, stage_pump_driver(e, &t));
    STAGE(ECU_STAGE_ACTUATOR_TESTS, stage_actuator_tests(e, in, &t));
    STAGE(ECU_STAGE_HEALTH, stage_health(e, in, &t));
    STAGE(ECU_STAGE_LOGBOOK, stage_logbook(e, &t));
    e->rate_q24 = t.rate;
    return &e->o;
}

/* ---- state digest and parameter load ------------------------------------------------------- */

/* the state's words in member order: each word's bytes copied out of the object
 * representation (well defined for any layout; the static assertions above make the words the
 * fields, with no padding between them) */
uint32_t ecu_state_digest(const ecu_state_t *s)
{
    const unsigned char *bytes = (const unsigned char *)s;
    uint32_t h = 2166136261u;
    int32_t w;
    size_t k;
    for (k = 0; k < (size_t)ECU_STATE_WORDS; k++) {
        memcpy(&w, bytes + k * sizeof w, sizeof w);
        h = (h ^ (uint32_t)w) * 16777619u;
    }
    return h;
}

/* the word index of a parameter field (no padding: see the static assertions above) */
#define PARAM_INDEX(field) ((int)(offsetof(ecu_params_t, field) / sizeof(int32_t)))

int ecu_params_load(ecu_params_t *p, const int32_t *words, size_t n)
{
    if (n != (size_t)ECU_PARAM_WORDS) {
        return ECU_PARAM_WORDS;
    }
    memcpy(p, words, sizeof *p); /* the words in member order (ECU_PARAM_FIELDS) */
    /* what the tick's indexing and divisions rely on; the rest is checked by compile_params */
    if (p->rate_hz < 1 || p->rate_hz > ECU_RATE_MAX_HZ) {
        return PARAM_INDEX(rate_hz);
    }
    if (p->controller < ECU_CTRL_MRAC || p->controller > ECU_CTRL_PI) {
        return PARAM_INDEX(controller);
    }
    if (p->rate_half_window < 1 || 2 * p->rate_half_window + 1 >= ECU_RATE_BUF_LEN) {
        return PARAM_INDEX(rate_half_window);
    }
    if (p->pi_step_q24 < 1) {
        return PARAM_INDEX(pi_step_q24);
    }
    if (p->sched_step_q24 < 1) {
        return PARAM_INDEX(sched_step_q24);
    }
    return -1;
}

#ifdef ECU_WITH_NAMES
#define ECU_STR(x) #x
#define ECU_XSTR(x) ECU_STR(x)
#define ECU_X_NAME(name) #name " "
#define ECU_A_NAME(name, n) #name "[" ECU_XSTR(n) "] "
const char ecu_param_names[] = ECU_PARAM_FIELDS(ECU_X_NAME, ECU_A_NAME);
const char ecu_state_names[] = ECU_STATE_FIELDS(ECU_X_NAME, ECU_A_NAME);
const char ecu_input_names[] = ECU_INPUT_FIELDS(ECU_X_NAME, ECU_A_NAME);
const char ecu_output_names[] = ECU_OUTPUT_FIELDS(ECU_X_NAME, ECU_A_NAME);
#endif
