/*
 * ecu_node.h - the ECU as a CAN node: the C twin of ecu/node.py (EcuNode), frame for frame.
 *
 * The node sits between your CAN driver and the control core: it checks the received frames
 * (E2E, ecu_frames.h), keeps per frame kind the best status since the last tick (an OK frame
 * wins), holds Demands until their DemandTick, runs ecu_tick and packs the frames to send:
 * EcuStatus and EcuTelemetry when due (every_status / every_telemetry ticks), then EcuActuator,
 * always last. It does no I/O and reads no clock: each call returns the frames to send, in send
 * order, in an array you pass (at most ECU_NODE_MAX_OUT). Clocking (protocol/lockstep.py):
 *
 * - lockstep (config.lockstep = 1): one tick per PlantSensors frame, answered with ActuatorTick
 *   = SensorTick. When a Demand is due at that tick (the command node sends Demands with their
 *   tick) the tick waits for it (ecu_node_waiting() is then 1): the Demand frame runs it, or
 *   ecu_node_timeout() after your guard time runs it without. A sensor frame of a tick already
 *   run is counted and dropped (its values go to the next tick).
 * - real time (config.lockstep = 0): call ecu_node_period() once per period of your clock
 *   (1 / rate_hz); ActuatorTick counts the node's own ticks.
 *
 * Integration (your scheduler, your CAN driver; static allocation, no heap):
 *
 *     static ecu_params_t params;
 *     static ecu_t ecu;
 *     static ecu_node_t node;
 *     ecu_node_config_t c;
 *     ecu_can_frame_t out[ECU_NODE_MAX_OUT];
 *     int k, n;
 *
 *     ecu_params_load(&params, words, ECU_PARAM_WORDS);
 *     ecu_init(&ecu, &params);
 *     c.lockstep = 1;
 *     c.every_status = ecu_node_every(50, (uint32_t)params.rate_hz);  // DBC cycle times, ms
 *     c.every_telemetry = ecu_node_every(10, (uint32_t)params.rate_hz);
 *     c.every_demand = ecu_node_every(50, (uint32_t)params.rate_hz);
 *     ecu_node_init(&node, &ecu, &c);
 *
 *     on each received frame (standard ID, 8 data bytes; other IDs are ignored):
 *         n = ecu_node_frame(&node, id, data, out);
 *     lockstep, nothing received for the guard time (a tick waits for its Demand, or the plant
 *     fell silent), and then every 1 / rate_hz of silence while ecu_node_own_clock() is 1:
 *         n = ecu_node_timeout(&node, out);
 *     real time, every 1 / rate_hz:
 *         n = ecu_node_period(&node, out);
 *     then: for (k = 0; k < n; k++) can_send(out[k].id, out[k].data);   // in this order
 *
 * The pump driver takes ecu.o.duty_cpct / ecu.o.pump_enable after each tick. A lockstep node
 * whose plant falls silent ticks on its own clock (ecu_node_own_clock() is 1, ActuatorTick + 1
 * per ecu_node_timeout()) until a sensor frame with a later tick comes back, so that the core
 * counts the lost sensor frames (and, past their timeout, goes to FAULT).
 *
 * All calls run in bounded time (fixed-length loops only), use integers only and never block. One
 * node per ecu_t; the node does not own the ecu_t and keeps a pointer to it. Not reentrant per
 * instance: call it from one context (or lock around the calls).
 */
#ifndef ECU_NODE_H
#define ECU_NODE_H

#include <stddef.h>
#include <stdint.h>

#include "ecu_core.h"
#include "ecu_frames.h"
#include "ecu_xcp.h"

#ifdef __cplusplus
extern "C" {
#endif

#define ECU_NODE_MAX_OUT 4 /* frames one call can send: EcuStatus, EcuTelemetry, EcuStarter,
                              EcuActuator */

/*
 * The two public records, as X-macro lists (the struct below and, in host builds, the field
 * names and types the Python wrapper reads its layout from). X(type, name) is one field;
 * A(type, name, n) an array.
 */

/* a classical CAN frame: standard ID, 8-byte payload (every frame of the contract has 8) */
#define ECU_CAN_FRAME_FIELDS(X, A) \
    X(uint32_t, id) \
    A(uint8_t, data, 8)

/* the node's configuration (EcuNode's lockstep and every_* of protocol.lockstep.every_ticks) */
#define ECU_NODE_CONFIG_FIELDS(X, A) \
    X(uint8_t, lockstep)          /* 1: lockstep, 0: real time (see above) */ \
    X(uint16_t, every_status)     /* EcuStatus every N ticks: ecu_node_every(50, rate_hz) */ \
    X(uint16_t, every_telemetry)  /* EcuTelemetry every N ticks: ecu_node_every(10, rate_hz) */ \
    X(uint16_t, every_demand)     /* Demands due every N ticks: ecu_node_every(50, rate_hz) */

#define ECU_NODE_X_FIELD(type, name) type name;
#define ECU_NODE_A_FIELD(type, name, n) type name[n];

typedef struct { ECU_CAN_FRAME_FIELDS(ECU_NODE_X_FIELD, ECU_NODE_A_FIELD) } ecu_can_frame_t;
typedef struct { ECU_NODE_CONFIG_FIELDS(ECU_NODE_X_FIELD, ECU_NODE_A_FIELD) } ecu_node_config_t;

/* a held Demand's raw values (EcuNode._demand_raw / _demand_next) */
typedef struct {
    uint8_t arm, stop;
    uint16_t demand_cpct, open_loop_mv;
    uint16_t tick; /* DemandTick */
} ecu_node_demand_t;

/*
 * All node state (allocate it statically; its fields are the node's own, read them through the
 * functions below). The names are EcuNode's.
 */
typedef struct {
    ecu_t *ecu;                /* the core (not owned) */
    ecu_node_config_t c;
    ecu_frames_t frames;       /* E2E receive state, alive counters, telemetry index */
    ecu_inputs_t in;           /* the next tick's inputs (EcuNode.i) */
    ecu_node_demand_t held[2]; /* the Demands held until their tick: earliest, later */
    uint32_t ticks;            /* ticks run (modulo 2^32) */
    uint32_t late_sensor_frames;
    uint32_t demand_waits;
    int32_t demand_tick;       /* DemandTick of the last valid Demand (-1: none) */
    int32_t applied_tick;      /* DemandTick of the last Demand handed to the core (-1: none) */
    uint16_t tick;             /* tick number being answered (lockstep: SensorTick) */
    uint16_t status_phase;     /* ticks % every_status */
    uint16_t telemetry_phase;  /* ticks % every_telemetry */
    uint8_t demand_pending;    /* valid Demands held: 0, 1 or 2 */
    uint8_t ticked_demands;    /* the command node sends Demands with their tick (lockstep) */
    uint8_t waiting;           /* a sensor frame waits for its Demand */
    uint8_t sensor_seen;       /* a sensor frame has come */
    uint8_t own_clock;         /* lockstep, plant silent: ticking on ecu_node_timeout() */
    uint8_t ran;               /* a tick has run (EcuNode.ticks > 0) */
    uint8_t starter_on;        /* a bench test drove the starter or igniter in OFF last tick */
    ecu_xcp_t *xcp;            /* the XCP slave (ecu_node_attach_xcp), or NULL */
} ecu_node_t;

/*
 * Ticks between frames of a DBC cycle time at the ECU rate (protocol.lockstep.every_ticks):
 * max(1, cycle_time_ms * rate_hz / 1000 rounded half to even), saturated at 65535.
 */
uint16_t ecu_node_every(uint32_t cycle_time_ms, uint32_t rate_hz);

/*
 * Power-on state of the node (EcuNode.__init__). e: an initialised core (ecu_init), not owned;
 * *c is copied (an every_* of 0 is taken as 1).
 */
void ecu_node_init(ecu_node_t *n, ecu_t *e, const ecu_node_config_t *c);

/*
 * One received frame (EcuNode.on_frame): PlantSensors, PlantAnalog and Demand are handled, any
 * other ID is ignored. Returns the number of frames to send (0..ECU_NODE_MAX_OUT), in out[0..]
 * in send order: in lockstep a PlantSensors or a Demand frame may run a tick.
 */
int ecu_node_frame(ecu_node_t *n, uint32_t frame_id, const uint8_t data[8],
                   ecu_can_frame_t out[ECU_NODE_MAX_OUT]);

/*
 * Lockstep guard time passed with nothing received (EcuNode.on_timeout): runs the tick waiting
 * for its Demand without it (counted in ecu_node_demand_waits), or, once a sensor frame has
 * come, ticks on the node's own clock (tick + 1). Returns the number of frames in out[].
 */
int ecu_node_timeout(ecu_node_t *n, ecu_can_frame_t out[ECU_NODE_MAX_OUT]);

/* Real time: one tick of the node's own clock, tick = ticks % 65536 (EcuNode.on_period). */
int ecu_node_period(ecu_node_t *n, ecu_can_frame_t out[ECU_NODE_MAX_OUT]);

/*
 * The XCP slave on the node (EcuNode.attach_xcp), initialised on the node's core
 * (ecu_xcp_init); NULL: none. From then on its command frames (ID x->c.cmd_id) are taken, served
 * at the tick boundary before ecu_tick (in lockstep before the first sensor frame: as they
 * come, and on ecu_node_timeout), the bench's demand goes to the tick, and the DAQ lists are
 * sampled after it. The slave's packets go out through its send callback during the call, so
 * before the frames the call returns: a tick's DTOs precede its own frames.
 */
void ecu_node_attach_xcp(ecu_node_t *n, ecu_xcp_t *x);

/*
 * A received frame of dlc data bytes (0..8): the XCP slave's command frames at any length, the
 * contract's frames (ecu_node_frame) at 8 bytes only; any other is ignored.
 */
int ecu_node_receive(ecu_node_t *n, uint32_t frame_id, const uint8_t *data, uint8_t dlc,
                     ecu_can_frame_t out[ECU_NODE_MAX_OUT]);

/* sizeof(ecu_node_t), for hosts that allocate it (the Python wrapper). */
size_t ecu_node_size(void);

/* EcuNode's counters */
uint32_t ecu_node_ticks(const ecu_node_t *n);              /* ticks run (modulo 2^32) */
uint16_t ecu_node_tick(const ecu_node_t *n);               /* the tick answered last / next */
uint32_t ecu_node_late_sensor_frames(const ecu_node_t *n); /* lockstep: of a tick already run */
uint32_t ecu_node_demand_waits(const ecu_node_t *n);       /* ticks run without their Demand */
int ecu_node_own_clock(const ecu_node_t *n);   /* 1: plant silent, ticking on timeouts */
int ecu_node_sensor_seen(const ecu_node_t *n); /* 1: a sensor frame has come */
int ecu_node_waiting(const ecu_node_t *n);     /* 1: a tick waits for its Demand */
/* the inputs the next tick gets so far (EcuNode.i) */
const ecu_inputs_t *ecu_node_inputs(const ecu_node_t *n);

#ifdef ECU_NODE_PROFILE
/* Built with ECU_NODE_PROFILE, the node calls these right before and right after each ecu_tick
   (the firmware image times the control core with them: ecu_main.c); you provide them. */
void ecu_node_profile_begin(void);
void ecu_node_profile_end(void);
#endif

#ifdef ECU_WITH_NAMES
/* "type name" / "type name[n]" of each field, space separated (the Python wrapper reads them) */
extern const char ecu_can_frame_names[];
extern const char ecu_node_config_names[];
extern const int ecu_node_max_out; /* ECU_NODE_MAX_OUT */
#endif

#ifdef __cplusplus
}
#endif
#endif /* ECU_NODE_H */
