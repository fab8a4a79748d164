/*
 * replay.c - replay golden vectors (ecu/golden.py) through the C core and compare every integer.
 *
 *     replay FILE.gv        exit 0 and "OK <ticks> ticks" when every tick matches
 *
 * File layout (little-endian int32 words): magic "EGV1", then the counts of parameter, input and
 * output words and of ticks, the parameter words, and per tick the input words, the output words
 * and the FNV-1a digest of the state after the tick. Built for the host and, with newlib's
 * semihosting (rdimon), for the Cortex-M4 under QEMU: stdio here is only the test harness.
 *
 * With REPLAY_SYSTICK (Cortex-M4 under `qemu -icount shift=0`, where the virtual clock counts
 * instructions) the SysTick timer is read around every ecu_tick and around a calibration loop of
 * a known instruction count; the replayer prints "SYSTICK <tick counts> <calibration counts>
 * <calibration instructions>" (see sil/bench/port.py).
 *
 * With ECU_STAGE_PROFILE as well, the core calls ecu_stage_done after each stage of the tick
 * (ecu_core.h): the SysTick counts since the previous stage's end (the first stage's from the
 * call of ecu_tick) add up per stage, and the replayer prints "STAGES <hook counts> <hook
 * calls>" and per stage "<counts> <calls>": the hook's own cost, from back-to-back calls, for
 * the reader to take off each call.
 */
#include <stdio.h>

#include "ecu_core.h"

static ecu_params_t params;
static ecu_t ecu;

#ifdef REPLAY_SYSTICK
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define CALIBRATION_LOOPS 100000u /* two instructions each: subs, bne */

static uint32_t systick_since(uint32_t start) /* counts since `start` (24-bit down counter) */
{
    return (start - SYST_CVR) & 0xFFFFFFu;
}

static uint32_t calibrate(void)
{
    uint32_t n = CALIBRATION_LOOPS;
    uint32_t t0 = SYST_CVR;
    __asm__ volatile("1: subs %0, %0, #1\n bne 1b" : "+r"(n) : : "cc");
    return systick_since(t0);
}
#endif

#ifdef ECU_STAGE_PROFILE
#ifndef REPLAY_SYSTICK
#error "ECU_STAGE_PROFILE counts SysTick: build with REPLAY_SYSTICK"
#endif
#define HOOK_CALIBRATION_LOOPS 2500u /* four back-to-back hooks each */

static uint32_t stage_counts[ECU_STAGES + 1]; /* the last: the calibration's */
static uint32_t stage_calls[ECU_STAGES + 1];
static uint32_t stage_t0;

void ecu_stage_done(int stage)
{
    stage_counts[stage] += systick_since(stage_t0);
    stage_calls[stage]++;
    stage_t0 = SYST_CVR;
}

static void print_stages(void)
{
    int k;
    uint32_t n;
    stage_t0 = SYST_CVR;
    for (n = 0; n < HOOK_CALIBRATION_LOOPS; n++) {
        ecu_stage_done(ECU_STAGES);
        ecu_stage_done(ECU_STAGES);
        ecu_stage_done(ECU_STAGES);
        ecu_stage_done(ECU_STAGES);
    }
    printf("STAGES %lu %lu", (unsigned long)stage_counts[ECU_STAGES],
           (unsigned long)stage_calls[ECU_STAGES]);
    for (k = 0; k < ECU_STAGES; k++) {
        printf(" %lu %lu", (unsigned long)stage_counts[k], (unsigned long)stage_calls[k]);
    }
    printf("\n");
}
#endif

/* the records field by field, in their X-macro order (the golden vectors' word order) */
#define REPLAY_SET_X(name) r->name = w[k++];
#define REPLAY_SET_A(name, n) for (j = 0; j < (n); j++) { r->name[j] = w[k++]; }
#define REPLAY_GET_X(name) w[k++] = r->name;
#define REPLAY_GET_A(name, n) for (j = 0; j < (n); j++) { w[k++] = r->name[j]; }

static void inputs_from_words(ecu_inputs_t *r, const int32_t w[ECU_INPUT_WORDS])
{
    int j = 0, k = 0;
    (void)j; /* for the arrays (none so far) */
    ECU_INPUT_FIELDS(REPLAY_SET_X, REPLAY_SET_A)
}

static void outputs_to_words(const ecu_outputs_t *r, int32_t w[ECU_OUTPUT_WORDS])
{
    int j = 0, k = 0;
    (void)j; /* for the arrays (none so far) */
    ECU_OUTPUT_FIELDS(REPLAY_GET_X, REPLAY_GET_A)
}

static int read_words(FILE *f, int32_t *w, size_t n)
{
    unsigned char b[4];
    size_t k;
    for (k = 0; k < n; k++) {
        if (fread(b, 1, 4, f) != 4) {
            return -1;
        }
        w[k] = (int32_t)((uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 |
                         (uint32_t)b[3] << 24);
    }
    return 0;
}

static int replay(FILE *f, const char *path)
{
    static const int32_t layout[3] = {ECU_PARAM_WORDS, ECU_INPUT_WORDS, ECU_OUTPUT_WORDS};
    int32_t head[5];
    int32_t words[ECU_PARAM_WORDS];
    int32_t in_w[ECU_INPUT_WORDS];
    int32_t out_w[ECU_OUTPUT_WORDS + 1];
    int32_t o[ECU_OUTPUT_WORDS];
    ecu_inputs_t in;
    int32_t t, n_ticks;
    int k, bad;
#ifdef REPLAY_SYSTICK
    uint32_t counts = 0;
#endif
    if (read_words(f, head, 5) != 0 || head[0] != 0x31564745) { /* "EGV1" */
        printf("%s: not a golden-vector file (no EGV1 header)\n", path);
        return 2;
    }
    for (k = 0; k < 3; k++) {
        if (head[k + 1] != layout[k]) {
            printf("%s: header word %d is %ld, this build expects %ld\n", path, k + 1,
                   (long)head[k + 1], (long)layout[k]);
            return 2;
        }
    }
    n_ticks = head[4];
    if (read_words(f, words, ECU_PARAM_WORDS) != 0) {
        printf("%s: truncated in the parameters\n", path);
        return 2;
    }
    bad = ecu_params_load(&params, words, ECU_PARAM_WORDS);
    if (bad >= 0) {
        printf("%s: parameter word %d refused by ecu_params_load\n", path, bad);
        return 2;
    }
    ecu_init(&ecu, &params);
#ifdef REPLAY_SYSTICK
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 5u; /* enabled, processor clock, no interrupt */
#endif
    for (t = 0; t < n_ticks; t++) {
        const ecu_outputs_t *out;
        if (read_words(f, in_w, ECU_INPUT_WORDS) != 0 ||
            read_words(f, out_w, ECU_OUTPUT_WORDS + 1) != 0) {
            printf("%s: truncated at tick %ld\n", path, (long)t);
            return 2;
        }
        inputs_from_words(&in, in_w);
#ifdef REPLAY_SYSTICK
        {
            uint32_t t0 = SYST_CVR;
#ifdef ECU_STAGE_PROFILE
            stage_t0 = t0;
#endif
            out = ecu_tick(&ecu, &in);
            counts += systick_since(t0);
        }
#else
        out = ecu_tick(&ecu, &in);
#endif
        outputs_to_words(out, o);
        for (k = 0; k < ECU_OUTPUT_WORDS; k++) {
            if (o[k] != out_w[k]) {
                printf("MISMATCH tick %ld output word %d: python %ld, c %ld\n", (long)t, k,
                       (long)out_w[k], (long)o[k]);
                return 1;
            }
        }
        if (ecu_state_digest(&ecu.s) != (uint32_t)out_w[ECU_OUTPUT_WORDS]) {
            printf("MISMATCH tick %ld state digest: python %08lx, c %08lx\n", (long)t,
                   (unsigned long)(uint32_t)out_w[ECU_OUTPUT_WORDS],
                   (unsigned long)ecu_state_digest(&ecu.s));
            return 1;
        }
    }
#ifdef REPLAY_SYSTICK
    printf("SYSTICK %lu %lu %lu\n", (unsigned long)counts, (unsigned long)calibrate(),
           (unsigned long)(2u * CALIBRATION_LOOPS));
#endif
#ifdef ECU_STAGE_PROFILE
    print_stages();
#endif
    printf("OK %ld ticks\n", (long)n_ticks);
    return 0;
}

int main(int argc, char **argv)
{
    FILE *f;
    int rc;
    if (argc != 2) {
        printf("usage: replay FILE.gv\n");
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL) {
        printf("%s: cannot open\n", argv[1]);
        return 2;
    }
    rc = replay(f, argv[1]);
    fclose(f);
    return rc;
}
