/*
 * ecu_frames.c - E2E protection and the ECU's frames (see ecu_frames.h), mirroring
 * protocol/e2e.py, protocol/codec.py and the frame handling of ecu/node.py.
 */
#include "ecu_frames.h"

#include "generated/turbojet.h"

enum { RX_SENSORS, RX_ANALOG, RX_DEMAND };
enum { TX_ACTUATOR, TX_STATUS, TX_TELEMETRY, TX_STARTER };

static const uint16_t rx_data_id[3] = {
    ECU_E2E_DATA_ID_SENSORS, ECU_E2E_DATA_ID_ANALOG, ECU_E2E_DATA_ID_DEMAND
};
static const uint16_t tx_data_id[4] = {
    ECU_E2E_DATA_ID_ACTUATOR, ECU_E2E_DATA_ID_STATUS, ECU_E2E_DATA_ID_TELEMETRY,
    ECU_E2E_DATA_ID_STARTER
};

void ecu_frames_init(ecu_frames_t *f)
{
    int k;
    for (k = 0; k < 3; k++) {
        f->rx_last[k] = -1;
    }
    for (k = 0; k < 4; k++) {
        f->tx_counter[k] = 0;
    }
    f->telemetry_index = 0;
}

static uint8_t crc8_byte(uint8_t crc, uint8_t byte)
{
    unsigned r = (unsigned)crc ^ byte;
    int bit;
    for (bit = 0; bit < 8; bit++) {
        r = (r & 0x80u) ? (r << 1) ^ 0x1Du : r << 1;
    }
    return (uint8_t)r;
}

uint8_t ecu_e2e_crc(uint16_t data_id, const uint8_t data[8])
{
    uint8_t crc = crc8_byte(crc8_byte(0, (uint8_t)(data_id & 0xFFu)), (uint8_t)(data_id >> 8));
    int k;
    for (k = 1; k < 8; k++) {
        crc = crc8_byte(crc, data[k]);
    }
    return crc;
}

/* E2EChecker.check (protocol/e2e.py) with the ECU node's max_delta: the alive counter runs
   0..ECU_E2E_COUNTER_MODULO - 1, a step of 1..ECU_E2E_MAX_DELTA is OK */
static int e2e_check(ecu_frames_t *f, int kind, const uint8_t data[8])
{
    int counter = data[1] & 0x0F;
    int status;
    if (counter >= ECU_E2E_COUNTER_MODULO || ecu_e2e_crc(rx_data_id[kind], data) != data[0]) {
        return ECU_E2E_WRONGCRC; /* (15 is never sent: a corrupted frame) nothing remembered */
    }
    if (f->rx_last[kind] < 0) {
        status = ECU_E2E_OK;
    } else {
        int delta = (counter - f->rx_last[kind] + ECU_E2E_COUNTER_MODULO) % ECU_E2E_COUNTER_MODULO;
        if (delta == 0) {
            return ECU_E2E_REPEATED;
        }
        status = delta <= ECU_E2E_MAX_DELTA ? ECU_E2E_OK : ECU_E2E_WRONGSEQUENCE;
    }
    f->rx_last[kind] = (int8_t)counter;
    return status;
}

int ecu_frames_check(ecu_frames_t *f, uint32_t frame_id, const uint8_t data[8])
{
    switch (frame_id) {
    case ECU_FRAME_SENSORS: return e2e_check(f, RX_SENSORS, data);
    case ECU_FRAME_ANALOG: return e2e_check(f, RX_ANALOG, data);
    case ECU_FRAME_DEMAND: return e2e_check(f, RX_DEMAND, data);
    default: return -1;
    }
}

int ecu_frames_receive(ecu_frames_t *f, uint32_t frame_id, const uint8_t data[8],
                       ecu_inputs_t *in, int32_t *demand_tick)
{
    int status = ecu_frames_check(f, frame_id, data);
    if (status != ECU_E2E_OK) {
        return status;
    }
    if (frame_id == ECU_FRAME_SENSORS) {
        struct turbojet_plant_sensors_t m;
        (void)turbojet_plant_sensors_unpack(&m, data, 8u);
        in->tick = m.sensor_tick;
        in->speed_rpm = (int32_t)m.shaft_speed;
        in->egt_dk = m.egt;
    } else if (frame_id == ECU_FRAME_ANALOG) {
        struct turbojet_plant_analog_t m;
        (void)turbojet_plant_analog_unpack(&m, data, 8u);
        in->supply_mv = m.supply_voltage;
        in->pump_ma = m.pump_current;
    } else {
        struct turbojet_demand_t m;
        (void)turbojet_demand_unpack(&m, data, 8u);
        in->arm = m.arm_request;
        in->stop = m.stop_request;
        in->demand_cpct = m.speed_demand;
        in->open_loop_mv = m.pump_voltage_demand;
        *demand_tick = m.demand_tick;
    }
    return status;
}

/* raw value into [lo, hi] (the DBC range, ECU_RAW_*; the codec saturates, never wraps), for an
   unsigned signal (lo >= 0) */
static uint32_t sat_raw(int32_t x, int32_t lo, int32_t hi)
{
    return (uint32_t)(x < lo ? lo : (x > hi ? hi : x));
}

/*
 * The same for a signed signal: Est_* and Gain_* (Q7.24) in EcuTelemetry, whose DBC maximum,
 * 127.99999994, is just under (2^31 - 1) / 2^24, so the codec's raw range (protocol/codec.py)
 * ends at 2^31 - 2
 */
static int32_t sat_signed(int32_t x, int32_t lo, int32_t hi)
{
    return x < lo ? lo : (x > hi ? hi : x);
}

#define RAW(msg, sig) ECU_RAW_##msg##_##sig##_MIN, ECU_RAW_##msg##_##sig##_MAX

/* alive counter into byte 1, CRC into byte 0 */
static void protect(ecu_frames_t *f, int kind, uint8_t data[8])
{
    data[1] = (uint8_t)((data[1] & 0xF0u) | f->tx_counter[kind]);
    f->tx_counter[kind] = (uint8_t)(f->tx_counter[kind] + 1u < ECU_E2E_COUNTER_MODULO
                                        ? f->tx_counter[kind] + 1u : 0u);
    data[0] = ecu_e2e_crc(tx_data_id[kind], data);
}

void ecu_frames_actuator(ecu_frames_t *f, const ecu_outputs_t *o, uint8_t data[8])
{
    struct turbojet_ecu_actuator_t m;
    (void)turbojet_ecu_actuator_init(&m);
    m.pump_enable = (uint8_t)sat_raw(o->pump_enable, RAW(ECU_ACTUATOR, PUMP_ENABLE));
    m.actuator_mode = (uint8_t)sat_raw(o->mode, RAW(ECU_ACTUATOR, ACTUATOR_MODE));
    m.actuator_tick = (uint16_t)sat_raw(o->tick, RAW(ECU_ACTUATOR, ACTUATOR_TICK));
    m.pump_duty = (uint16_t)sat_raw(o->duty_cpct, RAW(ECU_ACTUATOR, PUMP_DUTY));
    m.pump_voltage_target = (uint16_t)sat_raw(o->pump_mv, RAW(ECU_ACTUATOR, PUMP_VOLTAGE_TARGET));
    (void)turbojet_ecu_actuator_pack(data, &m, 8u);
    protect(f, TX_ACTUATOR, data);
}

void ecu_frames_starter(ecu_frames_t *f, const ecu_outputs_t *o, uint8_t data[8])
{
    struct turbojet_ecu_starter_t m;
    (void)turbojet_ecu_starter_init(&m);
    m.igniter_on = (uint8_t)sat_raw(o->igniter, RAW(ECU_STARTER, IGNITER_ON));
    m.starter_tick = (uint16_t)sat_raw(o->tick, RAW(ECU_STARTER, STARTER_TICK));
    m.starter_duty = (uint16_t)sat_raw(o->starter_cpct, RAW(ECU_STARTER, STARTER_DUTY));
    m.sequencer_state = (uint8_t)sat_raw(o->seq_state, RAW(ECU_STARTER, SEQUENCER_STATE));
    m.abort_reason = (uint8_t)sat_raw(o->seq_reason, RAW(ECU_STARTER, ABORT_REASON));
    (void)turbojet_ecu_starter_pack(data, &m, 8u);
    protect(f, TX_STARTER, data);
}

void ecu_frames_status(ecu_frames_t *f, const ecu_outputs_t *o, uint8_t data[8])
{
    struct turbojet_ecu_status_t m;
    (void)turbojet_ecu_status_init(&m);
    m.ecu_mode = (uint8_t)sat_raw(o->mode, RAW(ECU_STATUS, ECU_MODE));
    m.fault_word = (uint16_t)sat_raw(o->fault_word, RAW(ECU_STATUS, FAULT_WORD));
    m.pump_health = (uint16_t)sat_raw(o->pump_health_pm, RAW(ECU_STATUS, PUMP_HEALTH));
    m.loop_owner = (uint8_t)sat_raw(o->owner, RAW(ECU_STATUS, LOOP_OWNER));
    m.reference_speed = (uint16_t)sat_raw(o->nref_cpct, RAW(ECU_STATUS, REFERENCE_SPEED));
    m.sensors_valid = (uint8_t)sat_raw(o->inputs_valid, RAW(ECU_STATUS, SENSORS_VALID));
    (void)turbojet_ecu_status_pack(data, &m, 8u);
    protect(f, TX_STATUS, data);
}

void ecu_frames_telemetry(ecu_frames_t *f, const ecu_t *e, uint8_t data[8])
{
    struct turbojet_ecu_telemetry_t m;
    const ecu_outputs_t *o = &e->o;
    (void)turbojet_ecu_telemetry_init(&m);
    m.telemetry_index = f->telemetry_index;
#define TELEMETRY(field, value, signal) m.field = sat_signed(value, RAW(ECU_TELEMETRY, signal))
    switch (f->telemetry_index) {
    case 0: TELEMETRY(est_ap21, o->ap21_q24, EST_AP21); break;
    case 1: TELEMETRY(est_ap22, o->ap22_q24, EST_AP22); break;
    case 2: TELEMETRY(est_lambda, o->lambda_q24, EST_LAMBDA); break;
    case 3: TELEMETRY(est_theta21, o->theta21_q24, EST_THETA21); break;
    case 4: TELEMETRY(est_theta22, o->theta22_q24, EST_THETA22); break;
    case 5: TELEMETRY(gain_kx1, o->kx1_q24, GAIN_KX1); break;
    case 6: TELEMETRY(gain_kx2, o->kx2_q24, GAIN_KX2); break;
    case 7: TELEMETRY(gain_kr, o->kr_q24, GAIN_KR); break;
    case 8: TELEMETRY(gain_kf1, o->kf1_q24, GAIN_KF1); break;
    case 9: TELEMETRY(gain_kf2, o->kf2_q24, GAIN_KF2); break;
    case 10: TELEMETRY(est_speed_dev, e->s.obs_n_q24, EST_SPEED_DEV); break;
    case 11: TELEMETRY(est_speed_rate, e->s.obs_v_q24, EST_SPEED_RATE); break;
    default: TELEMETRY(saturation_count, o->sat_events, SATURATION_COUNT); break;
    }
#undef TELEMETRY
    (void)turbojet_ecu_telemetry_pack(data, &m, 8u);
    protect(f, TX_TELEMETRY, data);
    f->telemetry_index = (uint8_t)(f->telemetry_index + 1u < ECU_TELEMETRY_COUNT
                                       ? f->telemetry_index + 1u : 0u);
}
