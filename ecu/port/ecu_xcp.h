/*
 * ecu_xcp.h - the ECU's XCP slave in C (ASAM MCD-1 XCP 1.x on classic CAN, MAX_CTO = MAX_DTO =
 * 8): the twin of ecu/xcp/slave.py, answer for answer. The commands, error packets, memory map,
 * seed and key, DAQ model and bench commands are the Python slave's (docs/calibration.md); what
 * it shares with it is generated from the Python definitions (generated/ecu_xcp_map.h).
 *
 * Sans-IO and allocation-free: one static ecu_xcp_t per ECU, the integrator's CAN driver and
 * clock behind the callbacks of ecu_xcp_config_t. The CAN node (ecu_node.h) calls it:
 *
 *   - ecu_xcp_receive() with each command frame (ID config.cmd_id; its length 0..8): queued,
 *     at most ECU_XCP_QUEUE wait (more are dropped and counted);
 *   - ecu_xcp_serve() at the tick boundary, before ecu_tick: the frames waiting are served in
 *     order (a write of parameters ends the tick's serving: one parameter-set check a tick),
 *     then one step of a store to flash under way; each answer goes out through config.send;
 *   - ecu_xcp_inputs() right before ecu_tick: the inputs the tick takes (the bench's demand while
 *     the bench is the demand source);
 *   - ecu_xcp_sample() after ecu_tick: the DAQ lists of the events the tick raised (event 0 every
 *     tick, event 1 every 100 ms), their DTOs through config.send.
 *
 * Bounded work: every call runs in bounded time without blocking (BUILD_CHECKSUM: at most
 * ECU_XCP_MAX_CHECKSUM bytes; a sample: at most ECU_XCP_MAX_ODTS DTOs). With nothing queued,
 * no store under way and no DAQ list running, serve and sample return at once.
 *
 * Calibration writes go through the checks of the Python parameter table where the target can
 * make them: each parameter within its raw limits (ERR_OUT_OF_RANGE), none unsafe in RUN while
 * in RUN (ERR_ACCESS_DENIED), the rules of the whole set among the parameters it writes and the
 * run's bounds (ERR_VERIFY); an accepted write recompiles the firmware words it feeds in
 * integers, bit for bit as compile_params does (ecu/port/xcp_run.py). The parameters whose
 * words need the PI design, a discretisation, exp or a division by another parameter are not
 * written here (ERR_WRITE_PROTECTED): they come with the calibration.
 *
 * The run record (config.run, ECU_XCP_RUN_WORDS int32 words written by
 * ecu.port.xcp_run.run_record) gives the identification, the raws of the parameters that are
 * no firmware word, the run's constants, recipes and bounds; it is read, never written, and
 * must outlive the slave (the image keeps it in its calibration block in flash).
 */
#ifndef ECU_XCP_H
#define ECU_XCP_H

#include <stddef.h>
#include <stdint.h>

#include "ecu_core.h"
#include "generated/ecu_xcp_map.h"

#ifdef __cplusplus
extern "C" {
#endif

/* what this slave holds (a Python slave given ecu.xcp.slave.Limits of these answers alike) */
#define ECU_XCP_QUEUE 10       /* command frames waiting for the tick boundary */
#define ECU_XCP_MAX_BS 8       /* master block mode: 8 frames, 48 bytes (a schedule of 12) */
#define ECU_XCP_MAX_DAQ 16     /* DAQ lists */
#define ECU_XCP_MAX_ODTS 16    /* ODTs of all lists: at most this many DTOs an event */
#define ECU_XCP_MAX_ENTRIES 32 /* ODT entries of all lists */

/* a packet to the master: data[0..len-1] on config.res_id */
typedef void (*ecu_xcp_send_fn)(void *ctx, uint32_t id, const uint8_t *data, uint8_t len);
/* the ECU's clock in us (DAQ timestamps, GET_DAQ_CLOCK), modulo 2^32 */
typedef uint32_t (*ecu_xcp_clock_fn)(void *ctx);
/* a store of the parameter set to flash: begin 1 when asked (0: under way, < 0: refused, no
   flash), then begin 0 once a tick until it returns 1 (stored) or < 0 (failed) */
typedef int (*ecu_xcp_store_fn)(void *ctx, int begin);

typedef struct {
    uint32_t cmd_id;           /* master -> ECU (ECU_XCP_DEFAULT_CMD_ID) */
    uint32_t res_id;           /* ECU -> master (ECU_XCP_DEFAULT_RES_ID) */
    uint32_t seed;             /* the seeds' generator (xorshift32), non-zero */
    const int32_t *run;        /* the run record, ECU_XCP_RUN_WORDS words */
    ecu_params_t *params;      /* the parameters the core runs on: written by DOWNLOAD */
    ecu_xcp_send_fn send;      /* required */
    ecu_xcp_clock_fn clock_us; /* NULL: the ECU's ticks times its period (simulated time) */
    ecu_xcp_store_fn store;    /* NULL: no flash (a store is ERR_ACCESS_DENIED) */
    void *ctx;                 /* handed to the callbacks */
} ecu_xcp_config_t;

/* the slave's counters (ecu.xcp.slave.Counters), X(type, name) */
#define ECU_XCP_COUNTER_FIELDS(X) \
    X(uint32_t, frames)          /* command frames received */ \
    X(uint32_t, served)          /* command frames served */ \
    X(uint32_t, responses)       /* positive responses sent */ \
    X(uint32_t, samples)         /* DAQ lists sampled */ \
    X(uint32_t, dtos)            /* DTOs sent */ \
    X(uint32_t, ticks)           /* ecu_xcp_sample calls */ \
    X(uint16_t, ignored)         /* frames while not connected (other than CONNECT) */ \
    X(uint16_t, empty)           /* frames with no command byte */ \
    X(uint16_t, queue_overflow)  /* frames dropped: too many waiting */ \
    X(uint16_t, blocks_aborted)  /* master blocks cut short by another command */ \
    X(uint16_t, events)          /* EV packets sent */ \
    X(uint16_t, stores)          /* parameter sets stored to flash */ \
    X(uint16_t, store_failures)

#define ECU_XCP_ERROR_KINDS 14 /* error packets sent, per error (ecu_xcp_error_codes) */
#define ECU_XCP_X_COUNTER(type, name) type name;
typedef struct {
    ECU_XCP_COUNTER_FIELDS(ECU_XCP_X_COUNTER)
    uint16_t errors[ECU_XCP_ERROR_KINDS];
} ecu_xcp_counters_t;

/* a DAQ list, an ODT (its entries: entries[first .. first + count - 1]) */
typedef struct {
    uint8_t odts, first_pid, event, prescaler, priority, count, flags;
} ecu_xcp_daq_t;
typedef struct {
    uint8_t first, count;
} ecu_xcp_odt_t;

/* All slave state (allocate it statically; read it through the functions below). */
typedef struct {
    ecu_xcp_config_t c;
    ecu_t *ecu;
    int32_t raws[ECU_XCP_STORED]; /* the parameters that are no firmware word */
    uint8_t queue[ECU_XCP_QUEUE][1 + ECU_XCP_MAX_CTO]; /* length, bytes */
    uint8_t q_head, q_count;
    uint8_t block[ECU_XCP_MAX_BS * (ECU_XCP_MAX_CTO - 2)]; /* a master block's bytes */
    uint8_t block_total, block_len; /* block_total 0: none under way */
    uint32_t block_address;
    uint32_t mta;
    uint32_t rng;
    uint8_t connected, locked, heavy, storing;
    uint8_t seed_resource, key_total, key_len; /* seed_resource 0: no seed asked for */
    uint8_t seed[ECU_XCP_SEED_LENGTH], key[ECU_XCP_KEY_LENGTH];
    /* DAQ */
    ecu_xcp_daq_t lists[ECU_XCP_MAX_DAQ];
    ecu_xcp_odt_t odts[ECU_XCP_MAX_ODTS];
    uint16_t entries[ECU_XCP_MAX_ENTRIES]; /* region << 12 | offset << 3 | size */
    uint8_t n_lists, n_odts, n_entries, phase;
    uint8_t ptr_list, ptr_odt, ptr_entry, ptr_set;
    uint16_t every_100ms, events_phase;
    /* the bench demand source (ecu/service/bench_demand.py, bench_control.py) */
    int32_t can_age, throttle_cpct, idle_cpct, max_cpct, hold_ticks;
    uint8_t engaged, arm, stop, stop_held, last_mode;
    /* the bench test function requested (ECU_TEST_*), its level and duration (bench_control.py) */
    int32_t test_level, test_ms;
    uint8_t test_request, test_taken;
    /* the measurement image's demand source, as of the tick it was first read in */
    uint8_t meas_source;
    int32_t meas_tick;
    ecu_xcp_counters_t n;
} ecu_xcp_t;

/*
 * Power-on state (not connected, CAL/PAG and DAQ locked); *c is copied. e: the core, its
 * parameters c->params (the same record e->p points at). Returns 0, or -1 when the run record
 * is unusable (then the slave must not be used).
 */
int ecu_xcp_init(ecu_xcp_t *x, ecu_t *e, const ecu_xcp_config_t *c);

/* A command frame of len bytes (0..8; more are cut to 8). */
void ecu_xcp_receive(ecu_xcp_t *x, const uint8_t *data, uint8_t len);

/* At the tick boundary, before the tick: the frames waiting, one store step. */
void ecu_xcp_serve(ecu_xcp_t *x);

/* Right before ecu_tick: the inputs it takes (in, or *bench with the bench's demand). */
const ecu_inputs_t *ecu_xcp_inputs(ecu_xcp_t *x, ecu_inputs_t *in, ecu_inputs_t *bench);

/* After ecu_tick: the DAQ lists of the events of this tick. */
void ecu_xcp_sample(ecu_xcp_t *x);

/* sizeof(ecu_xcp_t), for hosts that allocate it (the Python wrapper) */
size_t ecu_xcp_size(void);
/* the counters, the error code of errors[k] */
const ecu_xcp_counters_t *ecu_xcp_counters(const ecu_xcp_t *x);
uint8_t ecu_xcp_error_code(int k);
/* the raw value of parameter k of the table (ecu.service.param_table.TABLE order) */
int32_t ecu_xcp_raw(const ecu_xcp_t *x, int k);
/* 1 while connected; the bench's demand source (0 CAN, 1 BENCH, 2 NONE) */
int ecu_xcp_connected(const ecu_xcp_t *x);
int ecu_xcp_source(const ecu_xcp_t *x);

#ifdef ECU_WITH_NAMES
/* "type name" of each counter, space separated (the Python wrapper reads them) */
extern const char ecu_xcp_counter_names[];
extern const int ecu_xcp_limits[5]; /* QUEUE, MAX_BS, MAX_DAQ, MAX_ODTS, MAX_ENTRIES */
/* the slave's double arithmetic on IEEE bits (ecu_xcp.c; for tests) */
uint64_t ecu_xcp_fl(int op, uint64_t a, uint64_t b);
#endif

#ifdef __cplusplus
}
#endif
#endif /* ECU_XCP_H */
