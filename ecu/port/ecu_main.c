/*
 * ecu_main.c - the ECU firmware's main loop on a Cortex-M (see ecu_main.h, board.h).
 *
 * Start-up: board, calibration block (checked), SysTick calibration, control core, CAN node and
 * its XCP slave, watchdog, SysTick at the ECU rate. Then forever: every received frame goes to
 * the node (in lockstep a sensor frame runs a tick; an XCP command waits for the tick boundary,
 * or is served at once before the first sensor frame), the slave's packets go out as it makes
 * them and the node's frames after them in its order, the pump output follows each tick; in
 * lockstep a guard time of silence runs ecu_node_timeout(), in real time every SysTick period
 * runs ecu_node_period(); the watchdog is kicked once per loop and the core sleeps (WFI) until
 * an interrupt. All memory is static; nothing is allocated.
 */
#include "ecu_main.h"

#include "board.h"
#include "ecu_core.h"
#include "ecu_node.h"

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define SYST_ENABLE_CORE_CLOCK 5u /* enabled, processor clock */
#define SYST_TICKINT 2u
#define CALIBRATION_LOOPS 100000u /* two instructions each: subs, bne */

typedef struct {
    uint32_t flags, guard_ms, watchdog_ms;
    int32_t words[ECU_PARAM_WORDS];
} calibration_t;

static calibration_t cal;
static ecu_params_t params;
static ecu_t ecu;
static ecu_node_t node;
static ecu_xcp_t xcp;
static ecu_xcp_config_t xcp_config;
static volatile uint32_t periods; /* SysTick interrupts since start */
static uint32_t reload = 0xFFFFFFu;
static uint32_t core_start, core_counts;

void ecu_main_systick(void)
{
    periods++;
}

/* SysTick counts from `start` to now (a down counter reloading at `reload`; < one period) */
static uint32_t counts_since(uint32_t start)
{
    uint32_t now = SYST_CVR;
    return start >= now ? start - now : start + (reload + 1u) - now;
}

void ecu_node_profile_begin(void)
{
    core_start = SYST_CVR;
}

void ecu_node_profile_end(void)
{
    core_counts = counts_since(core_start);
}

static void console(const char *s)
{
    size_t n = 0;
    while (s[n] != '\0') {
        n++;
    }
    board_console_write(s, n);
}

static void console_u32(uint32_t v)
{
    char buf[11];
    size_t k = sizeof buf;
    do {
        buf[--k] = (char)('0' + v % 10u);
        v /= 10u;
    } while (v != 0u && k > 0u);
    board_console_write(&buf[k], sizeof buf - k);
}

static uint32_t le32(const uint8_t *b)
{
    return (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
}

static uint32_t crc32(const uint8_t *b, size_t n)
{
    uint32_t crc = 0xFFFFFFFFu;
    size_t i;
    int k;
    for (i = 0; i < n; i++) {
        crc ^= b[i];
        for (k = 0; k < 8; k++) {
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return ~crc;
}

/* Check and take the calibration block; NULL when accepted, else why not. */
static const char *load_calibration(const uint8_t *b, size_t len)
{
    const size_t xcp_at = ECU_CAL_HEADER_BYTES + 4u * (size_t)ECU_PARAM_WORDS;
    const size_t size = xcp_at + ECU_CAL_XCP_BYTES + 4u * ECU_XCP_RUN_WORDS + 4u;
    size_t k;
    if (b == NULL || len < size) {
        return "block too short";
    }
    if (le32(b) != ECU_CAL_MAGIC) {
        return "no ECUC magic (flash not programmed?)";
    }
    if (le32(b + 4) != ECU_CAL_VERSION) {
        return "version not supported";
    }
    if (le32(b + 20) != (uint32_t)ECU_PARAM_WORDS) {
        return "parameter word count differs from this build's";
    }
    if (crc32(b, size - 4u) != le32(b + size - 4u)) {
        return "CRC mismatch";
    }
    cal.flags = le32(b + 8);
    cal.guard_ms = le32(b + 12);
    cal.watchdog_ms = le32(b + 16);
    if (cal.guard_ms < 1u || cal.guard_ms > 3600000u) {
        return "lockstep guard out of 1..3600000 ms";
    }
    if (cal.watchdog_ms < 10u || cal.watchdog_ms > 10000u) {
        return "watchdog timeout out of 10..10000 ms";
    }
    for (k = 0; k < (size_t)ECU_PARAM_WORDS; k++) {
        cal.words[k] = (int32_t)le32(b + ECU_CAL_HEADER_BYTES + 4u * k);
    }
    if (ecu_params_load(&params, cal.words, (size_t)ECU_PARAM_WORDS) >= 0) {
        return "parameter refused by ecu_params_load";
    }
    if (params.rate_hz < 10 || (uint32_t)params.rate_hz > board_core_hz() / 16u) {
        return "rate out of the SysTick's range";
    }
    xcp_config.cmd_id = le32(b + xcp_at);
    xcp_config.res_id = le32(b + xcp_at + 4u);
    xcp_config.seed = le32(b + xcp_at + 8u);
    /* the run record, read in place (the block is word aligned in flash) */
    xcp_config.run = (const int32_t *)(const void *)(b + xcp_at + ECU_CAL_XCP_BYTES);
    if ((cal.flags & ECU_CAL_XCP) &&
        (xcp_config.cmd_id > 0x7FFu || xcp_config.res_id > 0x7FFu ||
         xcp_config.cmd_id == xcp_config.res_id || xcp_config.seed == 0u)) {
        return "XCP identifiers or seed out of range";
    }
    return NULL;
}

/* the XCP slave's packets: on the CAN link at once */
static void xcp_send(void *ctx, uint32_t id, const uint8_t *data, uint8_t len)
{
    (void)ctx;
    board_can_send(id, data, len);
}

/* the ECU's clock in real time: SysTick periods and the current period's counts, in us */
static uint32_t xcp_clock_us(void *ctx)
{
    uint32_t p, cvr;
    (void)ctx;
    do {
        p = periods;
        cvr = SYST_CVR;
    } while (p != periods);
    return (uint32_t)(((uint64_t)p * (reload + 1u) + (reload - cvr)) * 1000000u /
                      ((uint64_t)(reload + 1u) * (uint32_t)params.rate_hz));
}

/* SysTick counts of a loop of 2 * CALIBRATION_LOOPS instructions (on QEMU with -icount, the
   host turns counts into instructions with it; on a board, cycles per instruction) */
static void calibrate(void)
{
    uint32_t n = CALIBRATION_LOOPS;
    uint32_t t0;
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = SYST_ENABLE_CORE_CLOCK;
    t0 = SYST_CVR;
    __asm__ volatile("1: subs %0, %0, #1\n bne 1b" : "+r"(n) : : "cc");
    console("CAL ");
    console_u32(counts_since(t0));
    console(" ");
    console_u32(2u * CALIBRATION_LOOPS);
    console("\n");
}

/* the console's commands (ecu_main.h): a line at a time */
static void console_commands(void)
{
    static const char wdtest[] = "WDTEST";
    static size_t matched;
    static int other;
    char c;
    while (board_console_read(&c)) {
        if (c == '\r' || c == '\n') {
            if (matched == sizeof wdtest - 1u && !other) {
                console("WDTEST\n");
                board_pump_output(0, 0);
                for (;;) { /* no kick: the watchdog resets the board */
                }
            }
            matched = 0u;
            other = 0;
        } else if (matched < sizeof wdtest - 1u && c == wdtest[matched]) {
            matched++;
        } else {
            other = 1;
        }
    }
}

static void sleep_until_interrupt(uint32_t seen_periods)
{
    __asm__ volatile("cpsid i" ::: "memory");
    if (!board_can_pending() && periods == seen_periods) {
        __asm__ volatile("wfi" ::: "memory"); /* a pending interrupt wakes it, masked or not */
    }
    __asm__ volatile("cpsie i" ::: "memory");
}

/* The frames of one node call, in order; the pump output and the profile line after a tick. */
static void after_node_call(int n, const ecu_can_frame_t *out, uint32_t t0, uint32_t ticks)
{
    int k;
    uint32_t node_counts = counts_since(t0);
    for (k = 0; k < n; k++) {
        board_can_send(out[k].id, out[k].data, 8u);
    }
    if (ecu_node_ticks(&node) == ticks) {
        return;
    }
    board_pump_output(ecu.o.duty_cpct, ecu.o.pump_enable);
    if (cal.flags & ECU_CAL_PROFILE) {
        console("K ");
        console_u32(node_counts);
        console(" ");
        console_u32(core_counts);
        console("\n");
    }
}

static void refused(const char *why)
{
    console("CONFIG BAD ");
    console(why);
    console("\n");
    board_pump_output(0, 0);
    board_watchdog_start(1000u);
    for (;;) { /* frames are read and dropped; no tick runs */
        board_can_rx_t f;
        while (board_can_receive(&f)) {
        }
        board_watchdog_kick();
        sleep_until_interrupt(periods);
    }
}

int main(void)
{
    ecu_node_config_t c;
    ecu_can_frame_t out[ECU_NODE_MAX_OUT];
    board_can_rx_t f;
    const uint8_t *block;
    const char *why;
    size_t len;
    uint32_t guard_periods, last_event = 0u, done_periods = 0u;

    board_init();
    board_pump_output(0, 0);
    if (board_reset_by_watchdog()) {
        console("RESET watchdog\n");
    }
    calibrate();
    block = board_calibration(&len);
    why = load_calibration(block, len);
    if (why != NULL) {
        refused(why);
    }
    ecu_init(&ecu, &params);
    c.lockstep = (uint8_t)(cal.flags & ECU_CAL_LOCKSTEP);
    c.every_status = ecu_node_every(50u, (uint32_t)params.rate_hz); /* DBC cycle times, ms */
    c.every_telemetry = ecu_node_every(10u, (uint32_t)params.rate_hz);
    c.every_demand = ecu_node_every(50u, (uint32_t)params.rate_hz);
    ecu_node_init(&node, &ecu, &c);
    if (cal.flags & ECU_CAL_XCP) {
        xcp_config.params = &params;
        xcp_config.send = xcp_send;
        xcp_config.clock_us = c.lockstep ? NULL : xcp_clock_us; /* lockstep: simulated time */
        xcp_config.store = NULL; /* no flash for stores on this board */
        xcp_config.ctx = NULL;
        if (ecu_xcp_init(&xcp, &ecu, &xcp_config) != 0) {
            refused("XCP run record refused");
        }
        ecu_node_attach_xcp(&node, &xcp);
    }
    guard_periods = (uint32_t)(((uint64_t)cal.guard_ms * (uint32_t)params.rate_hz + 999u) / 1000u);
    console("READY ");
    console_u32((uint32_t)params.rate_hz);
    console(c.lockstep ? " 1\n" : " 0\n");
    board_watchdog_start(cal.watchdog_ms);
    reload = board_core_hz() / (uint32_t)params.rate_hz - 1u;
    SYST_CSR = 0u;
    SYST_RVR = reload;
    SYST_CVR = 0u;
    SYST_CSR = SYST_ENABLE_CORE_CLOCK | SYST_TICKINT;

    for (;;) {
        uint32_t p, t0, ticks;
        int n;
        while (board_can_receive(&f)) {
            if (f.extended || f.remote) {
                continue; /* not of the contract: never reaches the node */
            }
            t0 = SYST_CVR;
            ticks = ecu_node_ticks(&node);
            n = ecu_node_receive(&node, f.id, f.data, f.dlc, out); /* (8 bytes but XCP's) */
            after_node_call(n, out, t0, ticks);
            last_event = periods;
        }
        p = periods;
        if (c.lockstep) {
            if (p - last_event >= (ecu_node_own_clock(&node) ? 1u : guard_periods)) {
                t0 = SYST_CVR;
                ticks = ecu_node_ticks(&node);
                n = ecu_node_timeout(&node, out);
                after_node_call(n, out, t0, ticks);
                last_event = p;
            }
        } else if (p != done_periods) {
            done_periods = p; /* periods missed while busy are skipped, not run late */
            t0 = SYST_CVR;
            ticks = ecu_node_ticks(&node);
            n = ecu_node_period(&node, out);
            after_node_call(n, out, t0, ticks);
        }
        console_commands();
        board_watchdog_kick();
        sleep_until_interrupt(p);
    }
}
