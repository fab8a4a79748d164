/*
 * ecu_xcp.c - the ECU's XCP slave (see ecu_xcp.h), mirroring ecu/xcp/slave.py, daq.py and
 * memory.py and the bench of ecu/service/bench_control.py and bench_demand.py, answer for answer;
 * the names are theirs where they have one.
 */
#include "ecu_xcp.h"

#include <string.h>

/* a function kept out of its callers: its frame (a measurement image, a write's working set) is
   on the stack only on its own path (the stack bound adds frames along call chains) */
#ifdef __GNUC__
#define NOINLINE __attribute__((noinline))
#else
#define NOINLINE
#endif

#ifdef ECU_WITH_NAMES
#define ECU_XCP_X_NAME(type, name) #type " " #name " "
const char ecu_xcp_counter_names[] = ECU_XCP_COUNTER_FIELDS(ECU_XCP_X_NAME);
const int ecu_xcp_limits[5] = {ECU_XCP_QUEUE, ECU_XCP_MAX_BS, ECU_XCP_MAX_DAQ, ECU_XCP_MAX_ODTS,
                               ECU_XCP_MAX_ENTRIES};
#endif

/* ---- tables ------------------------------------------------------------------------------ */

static const struct {
    uint8_t code, minimum, resource;
} commands[] = {
#define ECU_XCP_X_COMMAND(code, minimum, resource) {code, minimum, resource},
    ECU_XCP_COMMAND_LIST(ECU_XCP_X_COMMAND)
};

static const int32_t limits[ECU_XCP_LIMIT_PAIRS][2] = ECU_XCP_LIMITS;
static const uint8_t param_limit[ECU_XCP_PARAMS] = ECU_XCP_PARAM_LIMIT;
static const uint8_t param_store[ECU_XCP_PARAMS] = ECU_XCP_PARAM_STORE;
static const int32_t axis[ECU_XCP_AXIS_POINTS] = ECU_XCP_AXIS;
static const char text_tail[] = ECU_XCP_TEXT_TAIL;
static const char secret[] = ECU_XCP_SECRET;
static const uint8_t error_codes[ECU_XCP_ERROR_KINDS] = {
    ECU_XCP_ERR_CMD_SYNCH, ECU_XCP_ERR_CMD_BUSY, ECU_XCP_ERR_DAQ_ACTIVE,
    ECU_XCP_ERR_CMD_UNKNOWN, ECU_XCP_ERR_CMD_SYNTAX, ECU_XCP_ERR_OUT_OF_RANGE,
    ECU_XCP_ERR_WRITE_PROTECTED, ECU_XCP_ERR_ACCESS_DENIED, ECU_XCP_ERR_ACCESS_LOCKED,
    ECU_XCP_ERR_SEQUENCE, ECU_XCP_ERR_DAQ_CONFIG, ECU_XCP_ERR_MEMORY_OVERFLOW,
    ECU_XCP_ERR_GENERIC, ECU_XCP_ERR_VERIFY,
};

/* the measurements: offset in the region, type, where the value is in ecu_t (SEQ_TIME, SOURCE:
   computed) */
enum { SEQ_TIME = 0xFFFE, SOURCE = 0xFFFF };
static const struct {
    uint8_t offset, type;
    uint16_t member;
} meas[ECU_XCP_MEASUREMENTS] = {
#define ECU_XCP_X_MEAS(offset, type, member) {offset, type, (uint16_t)offsetof(ecu_t, member)},
#define ECU_XCP_T_MEAS(offset, type) {offset, type, SEQ_TIME},
#define ECU_XCP_B_MEAS(offset, type) {offset, type, SOURCE},
    ECU_XCP_MEAS_LIST(ECU_XCP_X_MEAS, ECU_XCP_T_MEAS, ECU_XCP_B_MEAS)
};

static const struct {
    uint8_t kind, a, b, c;
} rules[] = {
#define ECU_XCP_X_RULE(kind, a, b, c) {kind, a, b, c},
    ECU_XCP_RULE_LIST(ECU_XCP_X_RULE)
};
static const int32_t rule_k[] = ECU_XCP_RULE_K;

/* the regions, in ecu.xcp.memory.MemoryMap's order */
enum { AXIS, TEXT, CAL, MEAS, BENCH, LOG, REGIONS, NO_REGION = 7 };
static const uint32_t region_base[REGIONS] = {ECU_XCP_AXIS_BASE, ECU_XCP_TEXT_BASE,
                                              ECU_XCP_CAL_BASE, ECU_XCP_MEAS_BASE,
                                              ECU_XCP_BENCH_BASE, ECU_XCP_LOG_BASE};
static const uint16_t region_size[REGIONS] = {4 * ECU_XCP_AXIS_POINTS, ECU_XCP_TEXT_SIZE,
                                              4 * ECU_XCP_PARAMS, ECU_XCP_MEAS_SIZE,
                                              4 * ECU_XCP_BENCH_WORDS, 4 * ECU_XCP_LOG_WORDS};
/* the logbook's words: where each is in ecu_t */
static const uint16_t log_member[ECU_XCP_LOG_WORDS] = {
#define ECU_XCP_X_LOG(member) (uint16_t)offsetof(ecu_t, member),
    ECU_XCP_LOG_LIST(ECU_XCP_X_LOG)
};

#define PROTECTED (ECU_XCP_RES_CAL_PAG | ECU_XCP_RES_DAQ)
#define NONE (-0x10000)                /* a handler's result: no answer (a block goes on) */
#define ERR(code) (-1 - (int)(code))   /* ... an error packet */
#define ERRX(code, extra) (-1 - ((int)(code) | (extra) << 8)) /* ... with extra bytes in r[2..] */
#define CAN_NEVER (1L << 30)           /* bench_demand: no CAN Demand ever (a large age) */
#define SELECTED 1u
#define RUNNING 2u
#define MODE_SET 4u
enum { FREED, DAQ_ALLOCATED, ODT_ALLOCATED, ENTRY_ALLOCATED };
enum { SRC_CAN, SRC_BENCH, SRC_NONE };

/* ---- bytes ------------------------------------------------------------------------------- */

static uint32_t le32(const uint8_t *b)
{
    return (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
}

static void put32(uint8_t *b, uint32_t v)
{
    b[0] = (uint8_t)v;
    b[1] = (uint8_t)(v >> 8);
    b[2] = (uint8_t)(v >> 16);
    b[3] = (uint8_t)(v >> 24);
}

static uint16_t le16(const uint8_t *b)
{
    return (uint16_t)(b[0] | b[1] << 8);
}

static uint16_t crc16(uint16_t crc, uint8_t byte)
{
    int k;
    crc ^= (uint16_t)(byte << 8);
    for (k = 0; k < 8; k++) {
        crc = (uint16_t)(crc & 0x8000u ? (unsigned)crc << 1 ^ 0x1021u : (unsigned)crc << 1);
    }
    return crc;
}

/* the firmware word w of the parameters (words in ECU_PARAM_FIELDS order) */
static int32_t word(const ecu_params_t *p, unsigned w)
{
    int32_t v;
    memcpy(&v, (const unsigned char *)p + 4u * w, sizeof v);
    return v;
}

static void set_word(ecu_params_t *p, unsigned w, int32_t v)
{
    memcpy((unsigned char *)p + 4u * w, &v, sizeof v);
}

/* parameter k's raw value: its firmware word, or its stored slot */
int32_t ecu_xcp_raw(const ecu_xcp_t *x, int k)
{
    return param_limit[k] & ECU_XCP_IDENTITY ? word(x->c.params, param_store[k])
                                             : x->raws[param_store[k]];
}

/* ---- IEEE double arithmetic in integers (what compile_params computes in floats) ----------- */

/* (-1)^neg * m * 2^e, m < 2^53: a double, rounded to nearest even as IEEE 754 does */
typedef struct {
    uint64_t m;
    int e, neg;
} fl_t;

static int bitlen(uint64_t v)
{
    int n = 0;
    while (v != 0u) {
        v >>= 1;
        n++;
    }
    return n;
}

/* hi:lo * 2^e exactly (sticky: further bits below lo, not all 0) rounded to 53 bits */
static fl_t fl_round(uint64_t hi, uint64_t lo, int e, int sticky, int neg)
{
    fl_t r;
    int n = bitlen(hi);
    if (n > 0) {
        sticky |= (lo & ((1ull << n) - 1u)) != 0u;
        lo = lo >> n | hi << (64 - n);
        e += n;
    }
    n = bitlen(lo) - 53;
    if (n > 0) {
        uint64_t rem = lo & ((1ull << n) - 1u), half = 1ull << (n - 1);
        lo >>= n;
        e += n;
        if (rem > half || (rem == half && (sticky || (lo & 1u)))) {
            lo++;
            if (lo >> 53) {
                lo >>= 1;
                e++;
            }
        }
    }
    r.m = lo;
    r.e = e;
    r.neg = neg;
    return r;
}

static fl_t fl_int(int64_t v, int e)
{
    return fl_round(0u, (uint64_t)(v < 0 ? -v : v), e, 0, v < 0);
}

/* slot k of the run's constants (IEEE bits, low word first) */
static fl_t fl_pool(const ecu_xcp_t *x, int k)
{
    const int32_t *w = x->c.run + ECU_XCP_RUN_POOL + 2 * k;
    uint64_t bits = (uint64_t)(uint32_t)w[0] | (uint64_t)(uint32_t)w[1] << 32;
    int exponent = (int)(bits >> 52 & 0x7FFu);
    fl_t r;
    r.m = bits & ((1ull << 52) - 1u);
    r.e = -1074;
    if (exponent != 0) {
        r.m |= 1ull << 52;
        r.e = exponent - 1075;
    }
    r.neg = (int)(bits >> 63);
    return r;
}

static fl_t fl_mul(fl_t a, fl_t b)
{
    uint64_t a0 = a.m & 0xFFFFFFFFu, a1 = a.m >> 32, b0 = b.m & 0xFFFFFFFFu, b1 = b.m >> 32;
    uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0;
    uint64_t mid = (p00 >> 32) + (p01 & 0xFFFFFFFFu) + (p10 & 0xFFFFFFFFu);
    uint64_t hi = a1 * b1 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
    return fl_round(hi, mid << 32 | (p00 & 0xFFFFFFFFu), a.e + b.e, 0, a.neg ^ b.neg);
}

static fl_t fl_div(fl_t a, fl_t b)
{
    uint64_t q = 0u;
    int k;
    if (a.m == 0u || b.m == 0u) {
        return a; /* (no divisor of a recipe is 0) */
    }
    while (!(a.m >> 52)) { /* both to 53 significant bits */
        a.m <<= 1;
        a.e--;
    }
    while (!(b.m >> 52)) {
        b.m <<= 1;
        b.e--;
    }
    for (k = 0; k < 56; k++) { /* a.m / b.m to 55 fractional bits */
        q <<= 1;
        if (a.m >= b.m) {
            a.m -= b.m;
            q |= 1u;
        }
        a.m <<= 1;
    }
    return fl_round(0u, q, a.e - b.e - 55, a.m != 0u, a.neg ^ b.neg);
}

/* round(v * 2^k) half to even (Python's round), at least 1 with at_least_1; 0 when it does not
   fit an int32 */
static int fl_to_int(fl_t v, int k, int at_least_1, int32_t *out)
{
    uint64_t q = v.m;
    int s = v.e + k;
    if (q == 0u) {
        /* 0 */
    } else if (s >= 0) {
        if (bitlen(q) + s > 32) {
            return 0;
        }
        q <<= s;
    } else if (-s >= 64) {
        q = 0u;
    } else {
        uint64_t rem = q & ((1ull << -s) - 1u), half = 1ull << (-s - 1);
        q >>= -s;
        if (rem > half || (rem == half && (q & 1u))) {
            q++;
        }
    }
    if (q > 0x7FFFFFFFu + (uint64_t)(v.neg != 0)) {
        return 0;
    }
    *out = v.neg ? (int32_t)(-(int64_t)q) : (int32_t)q;
    if (at_least_1 && *out < 1) {
        *out = 1;
    }
    return 1;
}

/* ceil(|v| * 2^k), saturated at 2^62 */
static int64_t fl_ceil(fl_t v, int k)
{
    int s = v.e + k;
    if (v.m == 0u) {
        return 0;
    }
    if (s >= 0) {
        return bitlen(v.m) + s > 62 ? (int64_t)1 << 62 : (int64_t)(v.m << s);
    }
    if (-s >= 64) {
        return v.m != 0u;
    }
    return (int64_t)(v.m >> -s) + ((v.m & ((1ull << -s) - 1u)) != 0u);
}

/* round(v / 2^s) half to even, v >= 0 */
static int64_t rne(int64_t v, int s)
{
    int64_t one = 1, q = v >> s, rem = v & ((one << s) - 1), half = one << (s - 1);
    return rem > half || (rem == half && (q & 1)) ? q + 1 : q;
}

static uint32_t isqrt(uint64_t v)
{
    uint64_t r = 0u, bit = 1ull << 62;
    while (bit > v) {
        bit >>= 2;
    }
    while (bit != 0u) {
        if (v >= r + bit) {
            v -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    return (uint32_t)r;
}

#ifdef ECU_WITH_NAMES
/* the arithmetic above on IEEE bits (host builds: tests compare it with the host's doubles):
   op 0 a * b, 1 a / b (normal, non-zero operands), 2 round(a * 2^k) (b: k), 0 when out of int32 */
static fl_t fl_bits(uint64_t bits)
{
    fl_t r;
    r.m = (bits & ((1ull << 52) - 1u)) | 1ull << 52;
    r.e = (int)(bits >> 52 & 0x7FFu) - 1075;
    r.neg = (int)(bits >> 63);
    return r;
}

uint64_t ecu_xcp_fl(int op, uint64_t a, uint64_t b)
{
    fl_t r;
    int32_t v = 0;
    if (op == 2) {
        return fl_to_int(fl_bits(a), (int)(int64_t)b, 0, &v) ? (uint64_t)(uint32_t)v : 1ull << 63;
    }
    r = op == 0 ? fl_mul(fl_bits(a), fl_bits(b)) : fl_div(fl_bits(a), fl_bits(b));
    while (r.m != 0u && !(r.m >> 52)) {
        r.m <<= 1;
        r.e--;
    }
    return (uint64_t)r.neg << 63 | (uint64_t)(r.e + 1075) << 52 | (r.m & ((1ull << 52) - 1u));
}
#endif

/* ---- a calibration write: checks, recipes, derived words ---------------------------------- */

/* the parameters as a write would leave them: `n` words from parameter `first` in `data` */
typedef struct {
    const ecu_xcp_t *x;
    const uint8_t *data;
    int first, n;
} view_t;

static int32_t cand(const view_t *v, int k)
{
    return k >= v->first && k < v->first + v->n ? (int32_t)le32(v->data + 4 * (k - v->first))
                                                 : ecu_xcp_raw(v->x, k);
}

static NOINLINE int rule_holds(const view_t *v, int kind, int a, int b, int c)
{
    int64_t A = cand(v, a), B = kind == ECU_XCP_RULE_NONDECREASING ? 0 : cand(v, b);
    int j;
    fl_t f;
    switch (kind) {
    case ECU_XCP_RULE_LT:
        return A < B;
    case ECU_XCP_RULE_LE:
        return A <= B;
    case ECU_XCP_RULE_LE_OFF:
        return A + rule_k[c] <= B;
    case ECU_XCP_RULE_SUM_LE:
        return A + B <= cand(v, c);
    case ECU_XCP_RULE_ZERO_OR_RANGE:
        return A == 0 || (A >= rule_k[c] && A + rule_k[c + 1] <= B);
    case ECU_XCP_RULE_GE_MUL: /* A >= fl(B * pool[c]) as reals: A >= ceil(fl * 2^24) */
        f = fl_mul(fl_int(B, -24), fl_pool(v->x, c));
        return f.neg || A >= fl_ceil(f, 24); /* (A > 0: its limits) */
    case ECU_XCP_RULE_NONDECREASING:
        for (j = 0; j + 1 < b; j++) {
            if (cand(v, a + j) > cand(v, a + j + 1)) {
                return 0;
            }
        }
        return 1;
    default: /* BELOW */
        for (j = 0; j < c; j++) {
            if (cand(v, a + j) >= cand(v, b + j)) {
                return 0;
            }
        }
        return 1;
    }
}

/* recipe r of the run record for raw value `raw`: its word into *out (0: it does not fit) */
static NOINLINE int recipe(const ecu_xcp_t *x, int r, int32_t raw, int32_t *out)
{
    const int32_t *w = x->c.run + ECU_XCP_RUN_RECIPES + 1 + 2 * r;
    uint32_t head = (uint32_t)w[0], ops = (uint32_t)w[1];
    fl_t v = fl_int(raw, -(int)(head >> 24 & 31u));
    int j;
    for (j = 0; j < 3; j++) {
        unsigned op = ops >> (6 * j) & 63u;
        if (op >> 4 == ECU_XCP_OP_MUL) {
            v = fl_mul(v, fl_pool(x, (int)(op & 15u)));
        } else if (op >> 4 == ECU_XCP_OP_DIV) {
            v = fl_div(v, fl_pool(x, (int)(op & 15u)));
        }
    }
    return fl_to_int(v, (int8_t)(head >> 16 & 0xFFu), (int)(head >> 29 & 1u), out);
}

/* round(fl(a * 2^ea * b) * 2^k) half to even: a product's word (0: it does not fit) */
static NOINLINE int product(int64_t a, int ea, fl_t b, int k, int32_t *out)
{
    return fl_to_int(fl_mul(fl_int(a, ea), b), k, 0, out);
}

/* max(1, round(fl(a * 2^ea / den))): a quotient's word (0: it does not fit) */
static NOINLINE int quotient(int64_t a, int ea, int32_t den, int32_t *out)
{
    return fl_to_int(fl_div(fl_int(a, ea), fl_int(den, 0)), 0, 1, out);
}

/* the words of several parameters (ecu/port/xcp_run.py DERIVED_WORDS), from the view: checked,
   and with `commit` written into the parameters; 0: one does not fit */
static NOINLINE int derive(const view_t *v, int commit)
{
    ecu_params_t *p = v->x->c.params;
    int32_t v0 = cand(v, ECU_XCP_P_TRIM_V) - cand(v, ECU_XCP_P_PUMP_DEAD_V);
    int32_t lam_v0, kb, cap, starter, ticks;
    int64_t target_dk, inlet_ck, day;
    cap = (int32_t)rne(((int64_t)cand(v, ECU_XCP_P_START_EGT_LIMIT_K) -
                        cand(v, ECU_XCP_P_START_EGT_MARGIN_K)) * 10, 16);
    target_dk = rne((int64_t)cand(v, ECU_XCP_P_START_EGT_TARGET_K) * 10, 16);
    inlet_ck = rne((int64_t)cand(v, ECU_XCP_P_INLET_TEMP_K) * 100, 16);
    day = target_dk * inlet_ck / ECU_T_STD_CK;
    ticks = (int32_t)rne((int64_t)cand(v, ECU_XCP_P_START_STARTER_RAMP_S) * p->rate_hz, 16);
    if (!product(cand(v, ECU_XCP_P_LAMBDA_COMMISSIONED), -48, fl_int(v0, 0), 16, &lam_v0) ||
        !product(v0, -24, fl_pool(v->x, ECU_XCP_POOL_KBQ), 24, &kb) ||
        !quotient(((1L << 24) - cand(v, ECU_XCP_P_START_DUTY)) * 10000LL, -24,
                  ticks < 1 ? 1 : ticks, &starter)) {
        return 0;
    }
    if (commit) {
        p->pump_v0_q24 = v0;
        p->lam_comm_v0_q16 = lam_v0;
        p->init_theta_q24[ECU_KB] = kb;
        p->seq_egt_cap_dk = cap;
        p->seq_day_target_dk = (int32_t)(day < cap ? day : cap);
        p->ncor_k_q24 = (int32_t)isqrt(((uint64_t)ECU_T_STD_CK << 48) / (uint64_t)inlet_ck);
        p->seq_starter_step_cpct = starter;
    }
    return 1;
}

/* the recipes of the changed parameters: checked (commit 0) or applied (1); 0: one does not fit */
static int recipes(ecu_xcp_t *x, const view_t *v, int commit)
{
    int r, count = x->c.run[ECU_XCP_RUN_RECIPES];
    for (r = 0; r < count && r < ECU_XCP_MAX_RECIPES; r++) {
        uint32_t head = (uint32_t)x->c.run[ECU_XCP_RUN_RECIPES + 1 + 2 * r];
        int k = (int)(head & 0xFFu);
        int32_t w;
        if (k < v->first || k >= v->first + v->n || cand(v, k) == ecu_xcp_raw(x, k)) {
            continue;
        }
        if (!recipe(x, r, cand(v, k), &w)) {
            return 0;
        }
        if (commit) {
            set_word(x->c.params, head >> 8 & 0xFFu, w);
        }
    }
    return 1;
}

/* _write_parameters: words n from parameter `first` (XcpSlave._write_parameters and
   ParamTable.check_writes): 0, or the error */
static NOINLINE int write_params(ecu_xcp_t *x, int first, int n, const uint8_t *data)
{
    view_t v;
    int k, changed = 0, running = x->ecu->o.mode == ECU_RUN;
    const int32_t *bound = x->c.run + ECU_XCP_RUN_BOUNDS;
    if (x->locked & ECU_XCP_RES_CAL_PAG) {
        return ERR(ECU_XCP_ERR_ACCESS_LOCKED);
    }
    v.x = x;
    v.data = data;
    v.first = first;
    v.n = n;
    for (k = first; k < first + n; k++) { /* each write: in its limits, safe in RUN */
        int32_t raw = cand(&v, k);
        uint8_t lim = param_limit[k];
        if (raw == ecu_xcp_raw(x, k)) {
            continue;
        }
        changed = 1;
        if (raw < limits[lim & 0x3Fu][0] || raw > limits[lim & 0x3Fu][1]) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        if (running && !(lim & ECU_XCP_RUN_SAFE)) {
            return ERR(ECU_XCP_ERR_ACCESS_DENIED);
        }
    }
    if (!changed) {
        return 0;
    }
    x->heavy = 1;
    for (k = first; k < first + n; k++) { /* the parameters the target compiles */
        if (cand(&v, k) != ecu_xcp_raw(x, k) &&
            !(x->c.run[ECU_XCP_RUN_WRITABLE + k / 32] >> (k % 32) & 1)) {
            return ERR(ECU_XCP_ERR_WRITE_PROTECTED);
        }
    }
    for (k = 0; k < ECU_XCP_MAX_BOUNDS && bound[3 * k] >= 0; k++) { /* the run's bounds */
        int32_t raw = cand(&v, bound[3 * k]);
        if (raw < bound[3 * k + 1] || raw > bound[3 * k + 2]) {
            return ERR(ECU_XCP_ERR_VERIFY);
        }
    }
    for (k = 0; k < (int)(sizeof rules / sizeof rules[0]); k++) { /* the set's rules */
        if (!rule_holds(&v, rules[k].kind, rules[k].a, rules[k].b, rules[k].c)) {
            return ERR(ECU_XCP_ERR_VERIFY);
        }
    }
    if (!recipes(x, &v, 0) || !derive(&v, 0)) {
        return ERR(ECU_XCP_ERR_VERIFY);
    }
    (void)recipes(x, &v, 1); /* accepted: from the next tick */
    (void)derive(&v, 1);
    for (k = first; k < first + n; k++) {
        int32_t raw = cand(&v, k);
        if (param_limit[k] & ECU_XCP_IDENTITY) {
            set_word(x->c.params, param_store[k], raw);
        } else {
            x->raws[param_store[k]] = raw;
        }
    }
    return 0;
}

/* ---- the bench (ecu/service/bench_control.py, bench_demand.py) ---------------------------- */

static int32_t cpct(int32_t x_q24)
{
    return (int32_t)(((int64_t)x_q24 * 100 + (1 << 23)) >> 24);
}

static int can_present(const ecu_xcp_t *x)
{
    return x->can_age <= x->hold_ticks;
}

int ecu_xcp_source(const ecu_xcp_t *x)
{
    return can_present(x) ? SRC_CAN : x->engaged ? SRC_BENCH : SRC_NONE;
}

static int running_mode(int32_t mode)
{
    return mode == ECU_ARMED || mode == ECU_RUN;
}

/* _take_demand: the bench as the demand source (refused while CAN Demands are) */
static int take_demand(ecu_xcp_t *x)
{
    if (can_present(x)) {
        return ERR(ECU_XCP_ERR_ACCESS_DENIED);
    }
    if (!x->engaged) { /* engage: bumpless */
        int run = running_mode(x->ecu->o.mode);
        x->engaged = 1;
        x->arm = (uint8_t)run;
        x->stop = 0;
        x->throttle_cpct = run ? cpct(x->ecu->s.demand_q24) : x->idle_cpct;
    }
    return 0;
}

/* BenchControl.test: a bench test function (0: end the test) at the level and for the time set */
static int bench_test(ecu_xcp_t *x, int32_t kind)
{
    static const int32_t max_ms[4] = {0, ECU_TEST_MAX_MS_GLOW, ECU_TEST_MAX_MS_STARTER,
                                      ECU_TEST_MAX_MS_PRIME};
    const ecu_params_t *p = x->c.params;
    int32_t top;
    if (kind < ECU_TEST_NONE || kind > ECU_TEST_PRIME) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (kind == ECU_TEST_NONE) {
        x->test_request = ECU_TEST_NONE;
        return 0;
    }
    if (x->ecu->o.mode != ECU_OFF || can_present(x) || (x->engaged && x->arm)) {
        return ERR(ECU_XCP_ERR_ACCESS_DENIED);
    }
    top = kind == ECU_TEST_STARTER ? p->seq_start_cpct
          : kind == ECU_TEST_PRIME
              ? (int32_t)(((int64_t)p->seq_ign_v_max_q24 * 1000 + (1 << 23)) >> 24)
              : 0;
    if (x->test_ms < 1 || x->test_ms > max_ms[kind] ||
        (kind != ECU_TEST_GLOW && (x->test_level < 1 || x->test_level > top))) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    (void)take_demand(x);
    x->stop_held = 0;
    x->stop = 0;
    x->test_request = (uint8_t)kind;
    return 0;
}

/* _write_bench: words n from bench word `first` */
static NOINLINE int write_bench(ecu_xcp_t *x, int first, int n, const uint8_t *data)
{
    int k, r;
    for (k = first; k < first + n; k++, data += 4) {
        int32_t value = (int32_t)le32(data);
        if (k == ECU_XCP_BENCH_STOP) {
            if (value) { /* stop: always taken, held until the next arm; it ends a test */
                x->stop_held = 1;
                x->arm = 0;
                x->stop = 1;
                x->test_request = ECU_TEST_NONE;
            }
            continue;
        }
        if (x->locked & ECU_XCP_RES_CAL_PAG) {
            return ERR(ECU_XCP_ERR_ACCESS_LOCKED);
        }
        if (k == ECU_XCP_BENCH_ARM) {
            int32_t mode = x->ecu->o.mode;
            if (value != 0 && value != 1) {
                return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
            }
            if (!value) {
                continue;
            }
            if (mode == ECU_FAULT || mode == ECU_SHUTDOWN || !x->ecu->o.inputs_valid) {
                return ERR(ECU_XCP_ERR_ACCESS_DENIED);
            }
            x->stop_held = 0;
            x->test_request = ECU_TEST_NONE; /* an arm ends a test */
            if (!can_present(x)) {
                (void)take_demand(x);
                if (!running_mode(mode)) { /* a start from rest begins at idle */
                    x->throttle_cpct = x->idle_cpct;
                }
                x->arm = 1;
                x->stop = 0;
            }
        } else if (k == ECU_XCP_BENCH_THROTTLE) { /* 0.01 %N */
            if (value < 0 || value > x->max_cpct) {
                return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
            }
            r = take_demand(x);
            if (r) {
                return r;
            }
            x->throttle_cpct = value < x->idle_cpct ? x->idle_cpct : value;
        } else if (k == ECU_XCP_BENCH_TEST) {
            r = bench_test(x, value);
            if (r) {
                return r;
            }
        } else { /* the next test's level or duration */
            if (value < 0) {
                return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
            }
            if (k == ECU_XCP_BENCH_TEST_LEVEL) {
                x->test_level = value;
            } else {
                x->test_ms = value;
            }
        }
    }
    return 0;
}

const ecu_inputs_t *ecu_xcp_inputs(ecu_xcp_t *x, ecu_inputs_t *in, ecu_inputs_t *bench)
{
    int32_t mode = x->ecu->o.mode;
    int left_run = running_mode(x->last_mode) && !running_mode(mode);
    const ecu_inputs_t *ticked = in;
    if (in->demand_status == ECU_E2E_OK) {
        x->can_age = 0;
    } else if (x->can_age < CAN_NEVER) {
        x->can_age++;
    }
    if (x->engaged && can_present(x)) {
        x->engaged = 0; /* the CAN Demand wins while present */
    }
    x->last_mode = (uint8_t)mode;
    if (left_run) {
        x->throttle_cpct = x->idle_cpct; /* the run's demand ends with the run */
    }
    if (x->engaged) {
        if (left_run) {
            x->arm = 0; /* the start request is done: no retry by itself */
        }
        *bench = *in;
        bench->demand_cpct = x->throttle_cpct;
        bench->open_loop_mv = 0;
        bench->arm = x->ecu->s.rearm_wait ? 0 : x->arm;
        bench->stop = x->stop;
        bench->demand_status = ECU_E2E_OK;
        ticked = bench;
    } else if (x->stop_held) {
        in->stop = 1;
        x->ecu->s.stop = 1;
    }
    if (x->test_taken && x->ecu->s.test_active == ECU_TEST_NONE) {
        x->test_request = ECU_TEST_NONE; /* over (its time up, or ended by the firmware) */
    }
    x->test_taken = x->test_request != ECU_TEST_NONE;
    in->test_request = x->test_request;
    in->test_level = x->test_level;
    in->test_ms = x->test_ms;
    if (ticked != in) {
        bench->test_request = x->test_request;
        bench->test_level = x->test_level;
        bench->test_ms = x->test_ms;
    }
    return ticked;
}

/* ---- the memory map ---------------------------------------------------------------------- */

/* the region holding address .. address + size - 1 (REGIONS: none) and the offset in it */
static int locate(uint32_t address, uint32_t size, uint32_t *offset)
{
    int k;
    for (k = 0; k < REGIONS; k++) {
        uint32_t off = address - region_base[k];
        if (address >= region_base[k] && off <= region_size[k] && size <= region_size[k] - off) {
            *offset = off;
            return k;
        }
    }
    return REGIONS;
}

static int32_t saturate(int32_t v, int type)
{
    static const int32_t lo[4] = {0, 0, -0x8000, INT32_MIN};
    static const int32_t hi[4] = {0xFF, 0xFFFF, 0x7FFF, INT32_MAX};
    return v < lo[type] ? lo[type] : v > hi[type] ? hi[type] : v;
}

/* the measurement region after the last tick, each value saturated to its type */
static void meas_image(ecu_xcp_t *x, uint8_t img[ECU_XCP_MEAS_SIZE])
{
    const ecu_t *e = x->ecu;
    int k;
    if (e->s.ticks != x->meas_tick) { /* (the Python slave packs it once a tick) */
        x->meas_tick = e->s.ticks;
        x->meas_source = (uint8_t)ecu_xcp_source(x);
    }
    memset(img, 0, ECU_XCP_MEAS_SIZE);
    for (k = 0; k < ECU_XCP_MEASUREMENTS; k++) {
        int32_t v;
        uint8_t *b = img + meas[k].offset;
        if (meas[k].member == SEQ_TIME) {
            v = (int32_t)((int64_t)e->s.seq_timer * 1000 / x->c.params->rate_hz);
        } else if (meas[k].member == SOURCE) {
            v = x->meas_source;
        } else {
            memcpy(&v, (const unsigned char *)e + meas[k].member, sizeof v);
        }
        v = saturate(v, meas[k].type);
        b[0] = (uint8_t)v;
        if (meas[k].type != ECU_XCP_UBYTE) {
            b[1] = (uint8_t)((uint32_t)v >> 8);
        }
        if (meas[k].type == ECU_XCP_SLONG) {
            b[2] = (uint8_t)((uint32_t)v >> 16);
            b[3] = (uint8_t)((uint32_t)v >> 24);
        }
    }
}

static int32_t bench_word(const ecu_xcp_t *x, uint32_t k)
{
    return k == ECU_XCP_BENCH_ARM        ? (x->engaged ? x->arm : 0)
           : k == ECU_XCP_BENCH_STOP       ? x->stop_held
           : k == ECU_XCP_BENCH_THROTTLE   ? x->throttle_cpct
           : k == ECU_XCP_BENCH_TEST_LEVEL ? x->test_level
           : k == ECU_XCP_BENCH_TEST_MS    ? x->test_ms
                                           : x->ecu->s.test_active;
}

/* byte `off` of region `region` (img: the measurement image, packed by the caller) */
static uint8_t byte_at(const ecu_xcp_t *x, int region, uint32_t off, const uint8_t *img)
{
    uint32_t w;
    switch (region) {
    case AXIS:
        w = (uint32_t)axis[off / 4];
        break;
    case TEXT:
        if (off >= ECU_XCP_ID_LEN) {
            return (uint8_t)text_tail[off - ECU_XCP_ID_LEN];
        }
        w = (uint32_t)x->c.run[ECU_XCP_RUN_ID + off / 4];
        break;
    case CAL:
        w = (uint32_t)ecu_xcp_raw(x, (int)(off / 4));
        break;
    case MEAS:
        return img[off];
    case LOG:
        memcpy(&w, (const unsigned char *)x->ecu + log_member[off / 4], sizeof w);
        break;
    default:
        w = (uint32_t)bench_word(x, off / 4);
    }
    return (uint8_t)(w >> (8 * (off % 4)));
}

/* _read for UPLOAD: size (<= 7) bytes from address into out (0: not in the map) */
static NOINLINE int read_memory(ecu_xcp_t *x, uint32_t address, uint32_t size,
                       uint8_t out[ECU_XCP_MAX_CTO - 1])
{
    uint8_t img[ECU_XCP_MEAS_SIZE];
    uint32_t off, k;
    int region = locate(address, size, &off);
    if (region == REGIONS) {
        return 0;
    }
    if (region == MEAS) {
        meas_image(x, img);
    }
    for (k = 0; k < size && k < ECU_XCP_MAX_CTO - 1u; k++) {
        out[k] = byte_at(x, region, off + k, img);
    }
    return 1;
}

/* _write: data of n bytes at address, whole or refused whole; the MTA moves past it */
static int write_memory(ecu_xcp_t *x, uint32_t address, uint32_t n, const uint8_t *data)
{
    uint32_t off;
    int r, region = locate(address, n, &off);
    if (region == REGIONS) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (region != CAL && region != BENCH) {
        return ERR(ECU_XCP_ERR_WRITE_PROTECTED);
    }
    if (off % 4u || n % 4u) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    r = region == CAL ? write_params(x, (int)(off / 4), (int)(n / 4), data)
                      : write_bench(x, (int)(off / 4), (int)(n / 4), data);
    if (r == 0) {
        x->mta = address + n;
    }
    return r;
}

/* ---- DAQ (ecu/xcp/daq.py) ---------------------------------------------------------------- */

static int any_running(const ecu_xcp_t *x)
{
    int k;
    for (k = 0; k < x->n_lists; k++) {
        if (x->lists[k].flags & RUNNING) {
            return 1;
        }
    }
    return 0;
}

static void stop_all(ecu_xcp_t *x)
{
    int k;
    for (k = 0; k < x->n_lists; k++) {
        x->lists[k].flags &= (uint8_t)~(RUNNING | SELECTED);
    }
}

static void free_daq(ecu_xcp_t *x)
{
    x->n_lists = x->n_odts = x->n_entries = 0u;
    x->phase = FREED;
    x->ptr_set = 0u;
}

/* the list `number` (NULL: not allocated) */
static ecu_xcp_daq_t *daq_list(ecu_xcp_t *x, uint16_t number)
{
    return number < x->n_lists ? &x->lists[number] : NULL;
}

static int alloc_daq(ecu_xcp_t *x, uint16_t count)
{
    int k;
    if ((x->phase != FREED && x->phase != DAQ_ALLOCATED) || x->n_lists) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    if (count > ECU_XCP_MAX_DAQ) {
        return ERR(ECU_XCP_ERR_MEMORY_OVERFLOW);
    }
    for (k = 0; k < count; k++) {
        ecu_xcp_daq_t *d = &x->lists[k];
        d->odts = d->first_pid = d->event = d->priority = d->count = d->flags = 0u;
        d->prescaler = 1u;
    }
    x->n_lists = (uint8_t)count;
    x->phase = DAQ_ALLOCATED;
    return 0;
}

static int alloc_odt(ecu_xcp_t *x, uint16_t number, uint8_t count)
{
    ecu_xcp_daq_t *d = daq_list(x, number);
    int k, first = 0;
    if (x->phase != DAQ_ALLOCATED && x->phase != ODT_ALLOCATED) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    if (d == NULL) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (d->odts) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    if (x->n_odts + count > ECU_XCP_MAX_ODTS) {
        return ERR(ECU_XCP_ERR_MEMORY_OVERFLOW);
    }
    d->odts = count;
    x->n_odts = (uint8_t)(x->n_odts + count);
    for (k = 0; k < x->n_lists; k++) { /* absolute ODT numbers: the lists' ODTs in turn */
        x->lists[k].first_pid = (uint8_t)first;
        first += x->lists[k].odts;
    }
    for (k = 0; k < x->n_odts; k++) { /* no entries yet (they come after ALLOC_ODT) */
        x->odts[k].first = x->odts[k].count = 0u;
    }
    x->phase = ODT_ALLOCATED;
    return 0;
}

static int alloc_entries(ecu_xcp_t *x, uint16_t number, uint8_t odt, uint8_t count)
{
    ecu_xcp_daq_t *d = daq_list(x, number);
    ecu_xcp_odt_t *o;
    int k;
    if (x->phase != ODT_ALLOCATED && x->phase != ENTRY_ALLOCATED) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    if (d == NULL || odt >= d->odts) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    o = &x->odts[d->first_pid + odt];
    if (o->count) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    if (count > ECU_XCP_MAX_ODT_BYTES || x->n_entries + count > ECU_XCP_MAX_ENTRIES) {
        return ERR(ECU_XCP_ERR_MEMORY_OVERFLOW);
    }
    o->first = x->n_entries;
    o->count = count;
    for (k = 0; k < count; k++) {
        x->entries[x->n_entries + k] = NO_REGION << 12; /* not written: address 0, size 0 */
    }
    x->n_entries = (uint8_t)(x->n_entries + count);
    x->phase = ENTRY_ALLOCATED;
    return 0;
}

static int set_ptr(ecu_xcp_t *x, uint16_t number, uint8_t odt, uint8_t entry)
{
    ecu_xcp_daq_t *d = daq_list(x, number);
    if (d == NULL) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (d->flags & RUNNING) {
        return ERR(ECU_XCP_ERR_DAQ_ACTIVE);
    }
    if (odt >= d->odts || entry >= x->odts[d->first_pid + odt].count) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    x->ptr_list = (uint8_t)number;
    x->ptr_odt = odt;
    x->ptr_entry = entry;
    x->ptr_set = 1u;
    return 0;
}

static void advance_ptr(ecu_xcp_t *x, const ecu_xcp_odt_t *o)
{
    x->ptr_entry++;
    x->ptr_set = x->ptr_entry < o->count;
}

static int write_daq(ecu_xcp_t *x, uint8_t bit_offset, uint8_t size, uint8_t ext, uint32_t address)
{
    ecu_xcp_daq_t *d;
    ecu_xcp_odt_t *o;
    uint32_t off, used = 0u;
    int k, region;
    if (!x->ptr_set) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    d = &x->lists[x->ptr_list];
    o = &x->odts[d->first_pid + x->ptr_odt];
    if (d->flags & RUNNING) {
        return ERR(ECU_XCP_ERR_DAQ_ACTIVE);
    }
    if (bit_offset != 0xFFu || ext != 0u || size < 1u || size > ECU_XCP_MAX_ENTRY_SIZE) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    region = locate(address, size, &off);
    if (region == REGIONS) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    for (k = 0; k < o->count; k++) {
        if (k != x->ptr_entry) {
            used += x->entries[o->first + k] & 7u;
        }
    }
    if (used + size > ECU_XCP_MAX_ODT_BYTES) {
        return ERR(ECU_XCP_ERR_DAQ_CONFIG);
    }
    x->entries[o->first + x->ptr_entry] = (uint16_t)((unsigned)region << 12 | off << 3 | size);
    advance_ptr(x, o);
    return 0;
}

static int read_daq(ecu_xcp_t *x, uint8_t *r)
{
    const ecu_xcp_odt_t *o;
    unsigned e;
    if (!x->ptr_set) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    o = &x->odts[x->lists[x->ptr_list].first_pid + x->ptr_odt];
    e = x->entries[o->first + x->ptr_entry];
    r[1] = 0xFFu;
    r[2] = (uint8_t)(e & 7u);
    r[3] = 0u;
    put32(r + 4, e >> 12 == NO_REGION ? 0u : region_base[e >> 12] + (e >> 3 & 0x1FFu));
    advance_ptr(x, o);
    return 7;
}

static int set_mode(ecu_xcp_t *x, const uint8_t *f)
{
    ecu_xcp_daq_t *d = daq_list(x, le16(f + 2));
    uint16_t event = le16(f + 4);
    if (d == NULL) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (d->flags & RUNNING) {
        return ERR(ECU_XCP_ERR_DAQ_ACTIVE);
    }
    if (f[1] & (ECU_XCP_DAQ_MODE_ALTERNATING | ECU_XCP_DAQ_MODE_DIRECTION_STIM |
                ECU_XCP_DAQ_MODE_DTO_CTR | ECU_XCP_DAQ_MODE_PID_OFF) ||
        event >= ECU_XCP_EVENTS || f[6] < 1u) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    d->event = (uint8_t)event;
    d->prescaler = f[6];
    d->priority = f[7];
    d->flags |= MODE_SET;
    return 0;
}

/* _check_ready: ODTs, a mode, every entry written, room for the timestamp in the first ODT */
static int ready(const ecu_xcp_t *x, const ecu_xcp_daq_t *d)
{
    unsigned k, bytes = 0u;
    if (!d->odts || !(d->flags & MODE_SET)) {
        return 0;
    }
    for (k = 0; k < d->odts; k++) {
        const ecu_xcp_odt_t *o = &x->odts[d->first_pid + k];
        unsigned j;
        for (j = 0; j < o->count; j++) {
            unsigned size = x->entries[o->first + j] & 7u;
            if (!size) {
                return 0;
            }
            bytes += k == 0u ? size : 0u;
        }
    }
    return bytes + ECU_XCP_TIMESTAMP_SIZE <= ECU_XCP_MAX_ODT_BYTES;
}

static int start_stop(ecu_xcp_t *x, uint8_t mode, uint16_t number, uint8_t *r)
{
    ecu_xcp_daq_t *d = daq_list(x, number);
    if (d == NULL || mode > 2u) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (mode == 0u) {
        d->flags &= (uint8_t)~(RUNNING | SELECTED);
    } else if (!ready(x, d)) {
        return ERR(ECU_XCP_ERR_DAQ_CONFIG);
    } else if (mode == 1u) {
        d->flags |= RUNNING;
        d->count = 0u;
    } else {
        d->flags |= SELECTED;
    }
    r[1] = d->first_pid;
    return 1;
}

static int synch(ecu_xcp_t *x, uint8_t mode)
{
    int k;
    if (mode > 2u) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    for (k = 0; k < x->n_lists; k++) {
        ecu_xcp_daq_t *d = &x->lists[k];
        if (mode == 0u) {
            d->flags &= (uint8_t)~(RUNNING | SELECTED);
        } else if (d->flags & SELECTED) {
            d->flags &= (uint8_t)~SELECTED;
            if (mode == 1u) {
                d->flags |= RUNNING;
                d->count = 0u;
            } else {
                d->flags &= (uint8_t)~RUNNING;
            }
        }
    }
    return 0;
}

static uint32_t clock_us(const ecu_xcp_t *x)
{
    if (x->c.clock_us != NULL) {
        return x->c.clock_us(x->c.ctx);
    }
    return (uint32_t)((uint64_t)x->ecu->s.ticks * 1000000u / (uint32_t)x->c.params->rate_hz);
}

static void send(ecu_xcp_t *x, const uint8_t *data, uint8_t len)
{
    x->c.send(x->c.ctx, x->c.res_id, data, len);
}

/* the event happened: every running list on it, due by its prescaler, goes out */
static void sample_event(ecu_xcp_t *x, uint8_t event, uint32_t stamp, const uint8_t *img)
{
    int k;
    for (k = 0; k < x->n_lists; k++) {
        ecu_xcp_daq_t *d = &x->lists[k];
        unsigned j;
        int due;
        if (!(d->flags & RUNNING) || d->event != event) {
            continue;
        }
        due = d->count == 0u;
        d->count = (uint8_t)(d->count + 1u < d->prescaler ? d->count + 1u : 0u);
        if (!due) {
            continue;
        }
        x->n.samples++;
        for (j = 0; j < d->odts; j++) {
            const ecu_xcp_odt_t *o = &x->odts[d->first_pid + j];
            uint8_t dto[ECU_XCP_MAX_DTO];
            unsigned len = 1u, i, b;
            dto[0] = (uint8_t)(d->first_pid + j);
            if (j == 0u) {
                put32(dto + 1, stamp);
                len = 5u;
            }
            for (i = 0; i < o->count; i++) {
                unsigned e = x->entries[o->first + i];
                for (b = 0; b < (e & 7u); b++) {
                    dto[len++] = byte_at(x, (int)(e >> 12), (e >> 3 & 0x1FFu) + b, img);
                }
            }
            send(x, dto, (uint8_t)len);
            x->n.dtos++;
        }
    }
}

void ecu_xcp_sample(ecu_xcp_t *x)
{
    uint8_t img[ECU_XCP_MEAS_SIZE];
    uint32_t stamp;
    uint16_t k = x->events_phase;
    x->n.ticks++;
    x->events_phase = (uint16_t)(k + 1u < x->every_100ms ? k + 1u : 0u);
    if (!any_running(x)) {
        return;
    }
    stamp = clock_us(x);
    meas_image(x, img);
    sample_event(x, 0u, stamp, img);
    if (k == 0u) {
        sample_event(x, 1u, stamp, img);
    }
}

/* ---- commands (ecu/xcp/slave.py) --------------------------------------------------------- */

static uint32_t next_seed(ecu_xcp_t *x)
{
    uint32_t v = x->rng;
    v ^= v << 13;
    v ^= v >> 17;
    v ^= v << 5;
    x->rng = v;
    return v;
}

static int unlock(ecu_xcp_t *x, const uint8_t *f, uint8_t len)
{
    uint8_t remaining = f[1];
    unsigned take, k;
    uint16_t key = 0xFFFFu;
    if (!x->seed_resource) {
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    if (!x->key_len) {
        x->key_total = remaining;
    } else if (remaining != x->key_total - x->key_len) {
        x->seed_resource = 0u;
        return ERR(ECU_XCP_ERR_SEQUENCE);
    }
    take = remaining < ECU_XCP_MAX_CTO - 2u ? remaining : ECU_XCP_MAX_CTO - 2u;
    take = len - 2u < take ? len - 2u : take;
    for (k = 0; k < take; k++) {
        if (x->key_len < ECU_XCP_KEY_LENGTH) {
            x->key[x->key_len] = f[2 + k];
        }
        x->key_len = (uint8_t)(x->key_len + (x->key_len < 0xFFu));
    }
    if (x->key_len < x->key_total && x->key_len < 64u) {
        return 1;
    }
    for (k = 0; k < ECU_XCP_SEED_LENGTH; k++) { /* the service port's unlock_key */
        key = crc16(key, x->seed[k]);
    }
    for (k = 0; secret[k] != '\0'; k++) {
        key = crc16(key, (uint8_t)secret[k]);
    }
    k = x->seed_resource;
    x->seed_resource = 0u;
    if (x->key_total != ECU_XCP_KEY_LENGTH || x->key[0] != key >> 8 || x->key[1] != (key & 0xFFu)) {
        x->connected = 0u; /* a wrong key ends the session, as the standard says */
        x->locked = PROTECTED;
        return ERR(ECU_XCP_ERR_ACCESS_LOCKED);
    }
    x->locked &= (uint8_t)~k;
    return 1;
}

/* the MTA at a text of the text region; its length */
static int text(ecu_xcp_t *x, uint32_t at, int length)
{
    x->mta = ECU_XCP_TEXT_BASE + at;
    return length;
}

/* BUILD_CHECKSUM: CRC-16 CCITT over size bytes from the MTA, which moves past them */
static NOINLINE int checksum(ecu_xcp_t *x, uint32_t size, uint8_t *r)
{
    uint8_t img[ECU_XCP_MEAS_SIZE];
    uint32_t off, k;
    uint16_t crc = 0xFFFFu;
    int region;
    r[2] = r[3] = 0u;
    if (size < 1u || size > ECU_XCP_MAX_CHECKSUM) {
        put32(r + 4, ECU_XCP_MAX_CHECKSUM);
        return ERRX(ECU_XCP_ERR_OUT_OF_RANGE, 6);
    }
    region = locate(x->mta, size, &off);
    if (region == REGIONS) {
        return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
    }
    if (region == MEAS) {
        meas_image(x, img);
    }
    for (k = 0; k < size; k++) {
        crc = crc16(crc, byte_at(x, region, off + k, img));
    }
    x->mta += size;
    r[1] = ECU_XCP_CHECKSUM_CRC_16_CITT;
    put32(r + 4, crc);
    return 7;
}

/* one command: its answer in r[1..] (the result's length), NONE, or ERR/ERRX */
static int command(ecu_xcp_t *x, const uint8_t *f, uint8_t len, uint8_t *r)
{
    ecu_xcp_daq_t *d;
    uint32_t size, k;
    int n;
    switch (f[0]) {
    case ECU_XCP_CMD_CONNECT:
        if (f[1] > 1u) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        x->connected = 1u;
        x->locked = PROTECTED;
        x->seed_resource = 0u;
        x->block_total = 0u;
        stop_all(x);
        r[1] = PROTECTED;
        r[2] = ECU_XCP_COMM_MODE_BASIC_OPTIONAL;
        r[3] = ECU_XCP_MAX_CTO;
        r[4] = ECU_XCP_MAX_DTO;
        r[5] = 0u;
        r[6] = ECU_XCP_PROTOCOL_VERSION;
        r[7] = ECU_XCP_TRANSPORT_VERSION;
        return 7;
    case ECU_XCP_CMD_DISCONNECT:
        stop_all(x);
        free_daq(x);
        x->connected = 0u;
        x->locked = PROTECTED;
        x->seed_resource = 0u;
        return 0;
    case ECU_XCP_CMD_GET_STATUS:
        r[1] = (uint8_t)((x->storing ? ECU_XCP_SESSION_STORE_CAL_REQ : 0u) |
                         (any_running(x) ? ECU_XCP_SESSION_DAQ_RUNNING : 0u));
        r[2] = x->locked;
        r[3] = r[4] = r[5] = 0u;
        return 5;
    case ECU_XCP_CMD_SYNCH:
        return ERR(ECU_XCP_ERR_CMD_SYNCH);
    case ECU_XCP_CMD_GET_COMM_MODE_INFO:
        r[1] = 0u;
        r[2] = ECU_XCP_COMM_MODE_OPTIONAL_MASTER_BLOCK;
        r[3] = 0u;
        r[4] = ECU_XCP_MAX_BS;
        r[5] = r[6] = 0u;
        r[7] = ECU_XCP_DRIVER_VERSION;
        return 7;
    case ECU_XCP_CMD_GET_ID: /* types 0, 1, 2: uploaded from the MTA; others: length 0 */
        n = f[1] == ECU_XCP_ID_ASCII      ? text(x, 0u, ECU_XCP_ID_LEN)
            : f[1] == ECU_XCP_ID_A2L_NAME ? text(x, ECU_XCP_TEXT_A2L, ECU_XCP_TEXT_A2L_LEN)
            : f[1] == ECU_XCP_ID_A2L_FILE ? text(x, ECU_XCP_TEXT_A2L_FILE, ECU_XCP_TEXT_A2L_FILE_LEN)
                                          : 0;
        r[1] = r[2] = r[3] = 0u;
        put32(r + 4, (uint32_t)n);
        return 7;
    case ECU_XCP_CMD_SET_REQUEST:
        if (f[1] & (uint8_t)~ECU_XCP_REQUEST_STORE_CAL) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        if (!f[1]) {
            return 0;
        }
        if (x->c.store == NULL) {
            return ERR(ECU_XCP_ERR_ACCESS_DENIED);
        }
        if (x->storing) {
            return ERR(ECU_XCP_ERR_CMD_BUSY);
        }
        if (x->c.store(x->c.ctx, 1) < 0) {
            return ERR(ECU_XCP_ERR_ACCESS_DENIED);
        }
        x->storing = 1u;
        return 0;
    case ECU_XCP_CMD_GET_SEED:
        if (f[1] == 1u) { /* the remaining part: the whole seed went in the first */
            return ERR(ECU_XCP_ERR_SEQUENCE);
        }
        if (f[1] != 0u || (f[2] != ECU_XCP_RES_CAL_PAG && f[2] != ECU_XCP_RES_DAQ)) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        if (!(f[2] & x->locked)) {
            x->seed_resource = 0u;
            r[1] = 0u; /* not protected: no seed */
            return 1;
        }
        put32(x->seed, next_seed(x));
        for (k = 0; k < 2u; k++) { /* big-endian, as to_bytes(4, "big") */
            uint8_t t = x->seed[k];
            x->seed[k] = x->seed[3 - k];
            x->seed[3 - k] = t;
        }
        x->seed_resource = f[2];
        x->key_len = x->key_total = 0u;
        r[1] = ECU_XCP_SEED_LENGTH;
        memcpy(r + 2, x->seed, ECU_XCP_SEED_LENGTH);
        return 1 + ECU_XCP_SEED_LENGTH;
    case ECU_XCP_CMD_UNLOCK:
        n = unlock(x, f, len);
        r[1] = x->locked;
        return n;
    case ECU_XCP_CMD_SET_MTA:
        if (f[3] != 0u) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        x->mta = le32(f + 4);
        return 0;
    case ECU_XCP_CMD_UPLOAD:
    case ECU_XCP_CMD_SHORT_UPLOAD:
        size = f[1];
        k = f[0] == ECU_XCP_CMD_UPLOAD ? x->mta : le32(f + 4);
        if (size < 1u || size > ECU_XCP_MAX_CTO - 1u ||
            (f[0] == ECU_XCP_CMD_SHORT_UPLOAD && f[3] != 0u)) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        if (!read_memory(x, k, size, r + 1)) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        x->mta = k + size;
        return (int)size;
    case ECU_XCP_CMD_BUILD_CHECKSUM:
        return checksum(x, le32(f + 4), r);
    case ECU_XCP_CMD_DOWNLOAD:
        size = f[1];
        n = size < ECU_XCP_MAX_CTO - 2u ? (int)size : ECU_XCP_MAX_CTO - 2;
        if (size == 0u || size > ECU_XCP_MAX_BS * (ECU_XCP_MAX_CTO - 2u)) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        if (len < 2 + n) {
            return ERR(ECU_XCP_ERR_CMD_SYNTAX);
        }
        if (size > (uint32_t)n) { /* a master block: the rest in DOWNLOAD_NEXT frames */
            memcpy(x->block, f + 2, (size_t)n);
            x->block_total = (uint8_t)size;
            x->block_len = (uint8_t)n;
            x->block_address = x->mta;
            return NONE;
        }
        return write_memory(x, x->mta, size, f + 2);
    case ECU_XCP_CMD_DOWNLOAD_NEXT:
        if (!x->block_total) {
            r[2] = 0u;
            return ERRX(ECU_XCP_ERR_SEQUENCE, 1);
        }
        size = (uint32_t)(x->block_total - x->block_len); /* remaining */
        n = size < ECU_XCP_MAX_CTO - 2u ? (int)size : ECU_XCP_MAX_CTO - 2;
        if (f[1] != size) {
            x->block_total = 0u;
            r[2] = (uint8_t)size;
            return ERRX(ECU_XCP_ERR_SEQUENCE, 1);
        }
        if (len < 2 + n) {
            x->block_total = 0u;
            return ERR(ECU_XCP_ERR_CMD_SYNTAX);
        }
        memcpy(x->block + x->block_len, f + 2, (size_t)n);
        x->block_len = (uint8_t)(x->block_len + n);
        if (x->block_len < x->block_total) {
            return NONE;
        }
        x->block_total = 0u;
        return write_memory(x, x->block_address, x->block_len, x->block);
    case ECU_XCP_CMD_GET_DAQ_PROCESSOR_INFO:
        r[1] = ECU_XCP_DAQ_PROPERTY_DYNAMIC | ECU_XCP_DAQ_PROPERTY_PRESCALER |
               ECU_XCP_DAQ_PROPERTY_TIMESTAMP;
        r[2] = ECU_XCP_MAX_DAQ;
        r[3] = 0u;
        r[4] = ECU_XCP_EVENTS;
        r[5] = r[6] = r[7] = 0u;
        return 7;
    case ECU_XCP_CMD_GET_DAQ_RESOLUTION_INFO:
        r[1] = 1u;
        r[2] = ECU_XCP_MAX_ENTRY_SIZE;
        r[3] = 1u;
        r[4] = 0u;
        r[5] = ECU_XCP_TIMESTAMP_MODE;
        r[6] = 1u;
        r[7] = 0u;
        return 7;
    case ECU_XCP_CMD_GET_DAQ_EVENT_INFO:
        k = le16(f + 2);
        if (k >= ECU_XCP_EVENTS) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        r[1] = ECU_XCP_EVENT_PROPERTY_DAQ | ECU_XCP_EVENT_CONSISTENCY_EVENT;
        r[2] = 0xFFu;
        r[3] = (uint8_t)(k ? text(x, ECU_XCP_TEXT_EVENT1, ECU_XCP_TEXT_EVENT1_LEN)
                           : text(x, ECU_XCP_TEXT_EVENT0, ECU_XCP_TEXT_EVENT0_LEN));
        r[4] = (uint8_t)(k ? ECU_XCP_EVENT_100MS : 1000 / x->c.params->rate_hz);
        r[5] = ECU_XCP_UNIT_1MS;
        r[6] = (uint8_t)(1u - k);
        return 6;
    case ECU_XCP_CMD_GET_DAQ_LIST_INFO:
        d = daq_list(x, le16(f + 2));
        if (d == NULL) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        r[1] = 0x04u;
        r[2] = d->odts;
        r[3] = ECU_XCP_MAX_ODT_BYTES;
        r[4] = r[5] = 0xFFu;
        return 5;
    case ECU_XCP_CMD_FREE_DAQ:
        free_daq(x);
        return 0;
    case ECU_XCP_CMD_ALLOC_DAQ:
        return alloc_daq(x, le16(f + 2));
    case ECU_XCP_CMD_ALLOC_ODT:
        return alloc_odt(x, le16(f + 2), f[4]);
    case ECU_XCP_CMD_ALLOC_ODT_ENTRY:
        return alloc_entries(x, le16(f + 2), f[4], f[5]);
    case ECU_XCP_CMD_SET_DAQ_PTR:
        return set_ptr(x, le16(f + 2), f[4], f[5]);
    case ECU_XCP_CMD_WRITE_DAQ:
        return write_daq(x, f[1], f[2], f[3], le32(f + 4));
    case ECU_XCP_CMD_READ_DAQ:
        return read_daq(x, r);
    case ECU_XCP_CMD_CLEAR_DAQ_LIST:
        d = daq_list(x, le16(f + 2));
        if (d == NULL) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        d->flags &= (uint8_t)~(RUNNING | SELECTED);
        for (k = 0; k < d->odts; k++) {
            const ecu_xcp_odt_t *o = &x->odts[d->first_pid + k];
            unsigned j;
            for (j = 0; j < o->count; j++) {
                x->entries[o->first + j] &= (uint16_t)~7u;
            }
        }
        return 0;
    case ECU_XCP_CMD_SET_DAQ_LIST_MODE:
        return set_mode(x, f);
    case ECU_XCP_CMD_GET_DAQ_LIST_MODE:
        d = daq_list(x, le16(f + 2));
        if (d == NULL) {
            return ERR(ECU_XCP_ERR_OUT_OF_RANGE);
        }
        r[1] = (uint8_t)(ECU_XCP_DAQ_MODE_TIMESTAMP | (d->flags & RUNNING ? 0x40u : 0u) |
                         (d->flags & SELECTED ? 0x01u : 0u));
        r[2] = r[3] = 0u;
        r[4] = d->event;
        r[5] = 0u;
        r[6] = d->prescaler;
        r[7] = d->priority;
        return 7;
    case ECU_XCP_CMD_START_STOP_DAQ_LIST:
        return start_stop(x, f[1], le16(f + 2), r);
    case ECU_XCP_CMD_START_STOP_SYNCH:
        return synch(x, f[1]);
    default: /* GET_DAQ_CLOCK */
        r[1] = r[2] = r[3] = 0u;
        put32(r + 4, clock_us(x));
        return 7;
    }
}

static void count_error(ecu_xcp_t *x, uint8_t code)
{
    int k;
    for (k = 0; k < ECU_XCP_ERROR_KINDS; k++) {
        if (error_codes[k] == code) {
            x->n.errors[k]++;
            return;
        }
    }
}

static void answer_error(ecu_xcp_t *x, uint8_t code, uint8_t *r, uint8_t extra)
{
    r[0] = ECU_XCP_PID_ERR;
    r[1] = code;
    count_error(x, code);
    send(x, r, (uint8_t)(2u + extra));
}

/* _handle: one frame served */
static void handle(ecu_xcp_t *x, const uint8_t *f, uint8_t len)
{
    uint8_t r[ECU_XCP_MAX_CTO];
    unsigned k;
    int n;
    if (len == 0u) {
        x->n.empty++;
        return;
    }
    if (!x->connected && f[0] != ECU_XCP_CMD_CONNECT) {
        x->n.ignored++; /* a slave not connected answers CONNECT only */
        return;
    }
    x->n.served++;
    if (x->block_total && f[0] != ECU_XCP_CMD_DOWNLOAD_NEXT) {
        x->block_total = 0u; /* another command ends a block download */
        x->n.blocks_aborted++;
    }
    for (k = 0; k < sizeof commands / sizeof commands[0] && commands[k].code != f[0]; k++) {
    }
    if (k == sizeof commands / sizeof commands[0]) {
        answer_error(x, ECU_XCP_ERR_CMD_UNKNOWN, r, 0u);
        return;
    }
    if (len < commands[k].minimum) {
        answer_error(x, ECU_XCP_ERR_CMD_SYNTAX, r, 0u);
        return;
    }
    if (commands[k].resource & x->locked) {
        answer_error(x, ECU_XCP_ERR_ACCESS_LOCKED, r, 0u);
        return;
    }
    n = command(x, f, len, r);
    if (n >= 0) {
        r[0] = ECU_XCP_PID_RES;
        x->n.responses++;
        send(x, r, (uint8_t)(n + 1));
    } else if (n != NONE) {
        n = -1 - n;
        answer_error(x, (uint8_t)(n & 0xFF), r, (uint8_t)(n >> 8));
    }
}

void ecu_xcp_receive(ecu_xcp_t *x, const uint8_t *data, uint8_t len)
{
    uint8_t *slot;
    x->n.frames++;
    if (x->q_count >= ECU_XCP_QUEUE) {
        x->n.queue_overflow++;
        return;
    }
    if (len > ECU_XCP_MAX_CTO) {
        len = ECU_XCP_MAX_CTO;
    }
    slot = x->queue[(x->q_head + x->q_count) % ECU_XCP_QUEUE];
    memset(slot, 0, sizeof x->queue[0]);
    slot[0] = len;
    memcpy(slot + 1, data, len);
    x->q_count++;
}

void ecu_xcp_serve(ecu_xcp_t *x)
{
    unsigned k = x->q_count < ECU_XCP_MAX_FRAMES ? x->q_count : ECU_XCP_MAX_FRAMES;
    x->heavy = 0u;
    while (k-- > 0u) {
        const uint8_t *slot = x->queue[x->q_head];
        x->q_head = (uint8_t)((x->q_head + 1u) % ECU_XCP_QUEUE);
        x->q_count--;
        handle(x, slot + 1, slot[0]);
        if (x->heavy) {
            break; /* one parameter-set check a tick */
        }
    }
    if (x->storing) { /* one flash operation of the store under way */
        int done = x->c.store(x->c.ctx, 0);
        if (done < 0) {
            x->n.store_failures++;
            x->storing = 0u;
        } else if (done > 0) {
            uint8_t ev[2] = {ECU_XCP_PID_EV, ECU_XCP_EV_STORE_CAL};
            x->storing = 0u;
            x->n.stores++;
            x->n.events++;
            send(x, ev, 2u);
        }
    }
}

int ecu_xcp_init(ecu_xcp_t *x, ecu_t *e, const ecu_xcp_config_t *c)
{
    const ecu_params_t *p = c->params;
    uint32_t tenths;
    int k;
    memset(x, 0, sizeof *x);
    x->c = *c;
    x->ecu = e;
    if (c->run == NULL || c->send == NULL || p == NULL || p->rate_hz < 1 ||
        c->run[ECU_XCP_RUN_RECIPES] < 0 || c->run[ECU_XCP_RUN_RECIPES] > ECU_XCP_MAX_RECIPES) {
        return -1;
    }
    for (k = 0; k < ECU_XCP_STORED; k++) {
        x->raws[k] = c->run[ECU_XCP_RUN_STORED + k];
    }
    x->locked = PROTECTED;
    x->rng = c->seed ? c->seed : 1u;
    tenths = (uint32_t)p->rate_hz / 10u; /* max(1, round(rate_hz * 100 / 1000)), half to even */
    if ((uint32_t)p->rate_hz % 10u > 5u || ((uint32_t)p->rate_hz % 10u == 5u && (tenths & 1u))) {
        tenths++;
    }
    x->every_100ms = (uint16_t)(tenths < 1u ? 1u : tenths);
    x->can_age = CAN_NEVER;
    x->hold_ticks = p->demand_hold_ticks;
    x->idle_cpct = x->throttle_cpct = cpct(p->idle_q24);
    x->max_cpct = cpct(p->demand_max_q24);
    x->last_mode = ECU_OFF;
    x->meas_tick = -1;
    return 0;
}

size_t ecu_xcp_size(void)
{
    return sizeof(ecu_xcp_t);
}

const ecu_xcp_counters_t *ecu_xcp_counters(const ecu_xcp_t *x)
{
    return &x->n;
}

uint8_t ecu_xcp_error_code(int k)
{
    return k >= 0 && k < ECU_XCP_ERROR_KINDS ? error_codes[k] : 0xFFu;
}

int ecu_xcp_connected(const ecu_xcp_t *x)
{
    return x->connected;
}
