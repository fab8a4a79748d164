/*
 * ecu_node.c - the ECU's CAN node (see ecu_node.h), mirroring ecu/node.py (EcuNode) line by
 * line; the names are EcuNode's.
 */
#include "ecu_node.h"

#include "generated/turbojet.h"

#ifdef ECU_WITH_NAMES
#define ECU_NODE_X_NAME(type, name) #type " " #name " "
#define ECU_NODE_A_NAME(type, name, n) #type " " #name "[" #n "] "
const char ecu_can_frame_names[] = ECU_CAN_FRAME_FIELDS(ECU_NODE_X_NAME, ECU_NODE_A_NAME);
const char ecu_node_config_names[] = ECU_NODE_CONFIG_FIELDS(ECU_NODE_X_NAME, ECU_NODE_A_NAME);
const int ecu_node_max_out = ECU_NODE_MAX_OUT;
#endif

/* _ahead: tick is after now (16-bit lockstep ticks) */
static int ahead(uint16_t tick, uint16_t now)
{
    uint16_t d = (uint16_t)(tick - now);
    return d != 0u && d < 0x8000u;
}

/* protocol.lockstep.every_ticks: max(1, round(cycle_time_ms * rate_hz / 1000.0)); the quotient
   of two integers is a tie exactly when the remainder is 500, and Python's round takes the even */
uint16_t ecu_node_every(uint32_t cycle_time_ms, uint32_t rate_hz)
{
    uint32_t x, q, r;
    if (rate_hz != 0u && cycle_time_ms > UINT32_MAX / rate_hz) {
        return UINT16_MAX;
    }
    x = cycle_time_ms * rate_hz;
    q = x / 1000u;
    r = x % 1000u;
    if (r > 500u || (r == 500u && (q & 1u) != 0u)) {
        q++;
    }
    return (uint16_t)(q < 1u ? 1u : (q > UINT16_MAX ? UINT16_MAX : q));
}

#define ZERO_INPUT(name) n->in.name = 0;
#define NO_ARRAY(name, count)

void ecu_node_init(ecu_node_t *n, ecu_t *e, const ecu_node_config_t *c)
{
    n->ecu = e;
    n->c = *c;
    n->c.lockstep = (uint8_t)(c->lockstep != 0u);
    n->c.every_status = c->every_status ? c->every_status : 1u;
    n->c.every_telemetry = c->every_telemetry ? c->every_telemetry : 1u;
    n->c.every_demand = c->every_demand ? c->every_demand : 1u;
    ecu_frames_init(&n->frames);
    ECU_INPUT_FIELDS(ZERO_INPUT, NO_ARRAY) /* EcuInputs(): every field 0 */
    n->in.sensor_status = n->in.analog_status = n->in.demand_status = ECU_E2E_NONEWDATA;
    n->held[0].arm = n->held[0].stop = 0u;
    n->held[0].demand_cpct = n->held[0].open_loop_mv = n->held[0].tick = 0u;
    n->held[1] = n->held[0];
    n->ticks = 0u;
    n->starter_on = 0u;
    n->late_sensor_frames = 0u;
    n->demand_waits = 0u;
    n->demand_tick = -1;
    n->applied_tick = -1;
    n->tick = 0u;
    n->status_phase = n->telemetry_phase = 0u;
    n->demand_pending = 0u;
    n->ticked_demands = n->waiting = n->sensor_seen = n->own_clock = n->ran = 0u;
    n->xcp = NULL;
}

void ecu_node_attach_xcp(ecu_node_t *n, ecu_xcp_t *x)
{
    n->xcp = x;
}

/* _hold_demand: keep a valid Demand until its DemandTick (at once when unticked); two are held,
   a third replaces the later of the two (or both, when its tick is not after the earlier's) */
static void hold_demand(ecu_node_t *n, const uint8_t data[8])
{
    struct turbojet_demand_t m;
    ecu_node_demand_t d;
    (void)turbojet_demand_unpack(&m, data, 8u);
    d.arm = m.arm_request;
    d.stop = m.stop_request;
    d.demand_cpct = m.speed_demand;
    d.open_loop_mv = m.pump_voltage_demand;
    d.tick = m.demand_tick;
    if (n->demand_pending == 0u || !n->ticked_demands) {
        n->held[0] = d;
        n->demand_pending = 1u;
    } else if (ahead(d.tick, n->held[0].tick)) {
        n->held[1] = d;
        n->demand_pending = 2u;
    } else { /* the same or an earlier tick: it replaces the one held */
        n->held[1] = n->held[0];
        n->held[0] = d;
        n->demand_pending = 1u;
    }
    n->demand_tick = n->held[n->demand_pending == 2u ? 1 : 0].tick;
}

/* _demand_due: lockstep, a Demand is due at this tick and the one carrying it has not come */
static int demand_due(const ecu_node_t *n)
{
    int held;
    if (!n->ticked_demands || n->tick % n->c.every_demand != 0u) {
        return 0;
    }
    held = (n->demand_pending >= 1u && n->held[0].tick == n->tick)
           || (n->demand_pending == 2u && n->held[1].tick == n->tick);
    return !held && n->applied_tick != (int32_t)n->tick;
}

/* _apply_demand: the latest held Demand whose tick has come into the inputs (at once if
   unticked); one still ahead stays held. Only while one is held. */
static void apply_demand(ecu_node_t *n)
{
    const ecu_node_demand_t *d;
    if (n->ticked_demands) {
        if (ahead(n->held[0].tick, n->tick)) {
            return; /* DemandTick still ahead */
        }
        if (n->demand_pending == 2u && !ahead(n->held[1].tick, n->tick)) {
            n->held[0] = n->held[1];
            n->demand_pending = 1u; /* both due: the later one wins */
        }
    }
    d = &n->held[0];
    n->in.arm = d->arm;
    n->in.stop = d->stop;
    n->in.demand_cpct = d->demand_cpct;
    n->in.open_loop_mv = d->open_loop_mv;
    n->in.demand_status = ECU_E2E_OK;
    n->applied_tick = d->tick;
    if (n->demand_pending == 2u) {
        n->held[0] = n->held[1];
    }
    n->demand_pending--;
}

/* _run_tick: one firmware tick, then EcuStatus and EcuTelemetry when due, EcuStarter in ARMED
 * and SHUTDOWN or while a bench test function drives the starter or igniter, EcuActuator last */
static int run_tick(ecu_node_t *n, ecu_can_frame_t out[ECU_NODE_MAX_OUT])
{
    const ecu_outputs_t *o;
    const ecu_inputs_t *in = &n->in;
    ecu_inputs_t bench;
    int count = 0, drive;
    n->waiting = 0u;
    if (n->demand_pending) {
        apply_demand(n);
    }
    n->in.tick = n->tick;
    if (n->xcp != NULL) {
        ecu_xcp_serve(n->xcp); /* the master's requests, at the tick boundary */
        in = ecu_xcp_inputs(n->xcp, &n->in, &bench); /* the bench may be the demand source */
    }
#ifdef ECU_NODE_PROFILE
    ecu_node_profile_begin();
    o = ecu_tick(n->ecu, in);
    ecu_node_profile_end();
#else
    o = ecu_tick(n->ecu, in);
#endif
    if (n->xcp != NULL) {
        ecu_xcp_sample(n->xcp); /* the DAQ lists of this tick's events */
    }
    n->in.sensor_status = n->in.analog_status = n->in.demand_status = ECU_E2E_NONEWDATA;
    if (n->status_phase == 0u) { /* ticks % every_status == 0 */
        out[count].id = ECU_FRAME_STATUS;
        ecu_frames_status(&n->frames, o, out[count].data);
        count++;
    }
    if (n->telemetry_phase == 0u) { /* ticks % every_telemetry == 0 */
        out[count].id = ECU_FRAME_TELEMETRY;
        ecu_frames_telemetry(&n->frames, n->ecu, out[count].data);
        count++;
    }
    drive = o->mode == ECU_OFF && (o->starter_cpct > 0 || o->igniter);
    if (o->mode == ECU_ARMED || o->mode == ECU_SHUTDOWN || drive || n->starter_on) {
        out[count].id = ECU_FRAME_STARTER; /* (a test's outputs, and their end, in OFF) */
        ecu_frames_starter(&n->frames, o, out[count].data);
        count++;
    }
    n->starter_on = (uint8_t)drive;
    out[count].id = ECU_FRAME_ACTUATOR; /* ActuatorTick: o->tick, the echo of in.tick */
    ecu_frames_actuator(&n->frames, o, out[count].data);
    count++;
    n->ticks++;
    n->ran = 1u;
    n->status_phase = (uint16_t)(n->status_phase + 1u < n->c.every_status
                                     ? n->status_phase + 1u : 0u);
    n->telemetry_phase = (uint16_t)(n->telemetry_phase + 1u < n->c.every_telemetry
                                        ? n->telemetry_phase + 1u : 0u);
    return count;
}

/* an XCP command frame: queued for the tick boundary (no tick yet in lockstep: served at once) */
static void xcp_command(ecu_node_t *n, const uint8_t *data, uint8_t dlc)
{
    ecu_xcp_receive(n->xcp, data, dlc);
    if (n->c.lockstep && !n->sensor_seen) {
        ecu_xcp_serve(n->xcp);
    }
}

/* on_frame */
int ecu_node_frame(ecu_node_t *n, uint32_t frame_id, const uint8_t data[8],
                   ecu_can_frame_t out[ECU_NODE_MAX_OUT])
{
    ecu_inputs_t *in = &n->in;
    int status;
    if (frame_id == ECU_FRAME_SENSORS) {
        uint16_t tick = (uint16_t)(n->tick + 1u); /* a corrupt frame: taken as the next tick's */
        n->sensor_seen = 1u;
        status = ecu_frames_check(&n->frames, frame_id, data);
        if (in->sensor_status != ECU_E2E_OK) { /* an OK frame since the last tick wins */
            in->sensor_status = status;
        }
        if (status != ECU_E2E_WRONGCRC) { /* the CRC holds: the tick is the sender's */
            struct turbojet_plant_sensors_t m;
            (void)turbojet_plant_sensors_unpack(&m, data, 8u);
            tick = m.sensor_tick;
            if (status == ECU_E2E_OK) {
                in->speed_rpm = (int32_t)m.shaft_speed;
                in->egt_dk = m.egt;
            }
        }
        if (n->c.lockstep) {
            if (n->ran && !ahead(tick, n->tick)) {
                /* a tick already run: its values go to the next tick */
                n->late_sensor_frames++;
                return 0;
            }
            n->own_clock = 0u;
            n->tick = tick;
            if (n->ticked_demands && demand_due(n)) {
                n->waiting = 1u;
            } else {
                return run_tick(n, out);
            }
        }
    } else if (frame_id == ECU_FRAME_ANALOG) {
        status = ecu_frames_check(&n->frames, frame_id, data);
        if (status == ECU_E2E_OK) {
            struct turbojet_plant_analog_t m;
            (void)turbojet_plant_analog_unpack(&m, data, 8u);
            in->supply_mv = m.supply_voltage;
            in->pump_ma = m.pump_current;
        }
        if (in->analog_status != ECU_E2E_OK) { /* an OK frame since the last tick wins */
            in->analog_status = status;
        }
    } else if (frame_id == ECU_FRAME_DEMAND) {
        status = ecu_frames_check(&n->frames, frame_id, data);
        if (status == ECU_E2E_OK) {
            n->ticked_demands = n->c.lockstep;
            hold_demand(n, data);
        } else if (in->demand_status != ECU_E2E_OK) {
            in->demand_status = status;
        }
        if (n->waiting && !demand_due(n)) {
            return run_tick(n, out);
        }
    } else if (n->xcp != NULL && frame_id == n->xcp->c.cmd_id) {
        xcp_command(n, data, 8u);
    }
    return 0;
}

int ecu_node_receive(ecu_node_t *n, uint32_t frame_id, const uint8_t *data, uint8_t dlc,
                     ecu_can_frame_t out[ECU_NODE_MAX_OUT])
{
    if (n->xcp != NULL && frame_id == n->xcp->c.cmd_id) {
        xcp_command(n, data, dlc);
        return 0;
    }
    return dlc == 8u ? ecu_node_frame(n, frame_id, data, out) : 0;
}

/* on_timeout */
int ecu_node_timeout(ecu_node_t *n, ecu_can_frame_t out[ECU_NODE_MAX_OUT])
{
    if (n->waiting) {
        n->demand_waits++;
        return run_tick(n, out);
    }
    if (n->c.lockstep && n->sensor_seen) {
        n->own_clock = 1u; /* timeout_s = 1 / rate_hz */
        n->tick = (uint16_t)(n->tick + 1u);
        return run_tick(n, out);
    }
    if (n->xcp != NULL) { /* no plant heard yet: the slave, with the engine stopped */
        ecu_xcp_serve(n->xcp);
    }
    return 0;
}

/* on_period */
int ecu_node_period(ecu_node_t *n, ecu_can_frame_t out[ECU_NODE_MAX_OUT])
{
    n->tick = (uint16_t)n->ticks; /* ticks % 65536 */
    return run_tick(n, out);
}

size_t ecu_node_size(void)
{
    return sizeof(ecu_node_t);
}

uint32_t ecu_node_ticks(const ecu_node_t *n)
{
    return n->ticks;
}

uint16_t ecu_node_tick(const ecu_node_t *n)
{
    return n->tick;
}

uint32_t ecu_node_late_sensor_frames(const ecu_node_t *n)
{
    return n->late_sensor_frames;
}

uint32_t ecu_node_demand_waits(const ecu_node_t *n)
{
    return n->demand_waits;
}

int ecu_node_own_clock(const ecu_node_t *n)
{
    return n->own_clock;
}

int ecu_node_sensor_seen(const ecu_node_t *n)
{
    return n->sensor_seen;
}

int ecu_node_waiting(const ecu_node_t *n)
{
    return n->waiting;
}

const ecu_inputs_t *ecu_node_inputs(const ecu_node_t *n)
{
    return &n->in;
}
