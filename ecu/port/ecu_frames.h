/*
 * ecu_frames.h - the ECU's own CAN frames: pack and unpack with the code cantools generates from
 * protocol/turbojet.dbc (generated/turbojet.[ch]), plus the E2E protection of the contract:
 * CRC-8 (polynomial 0x1D, initial 0x00, no final XOR) in byte 0 over the data ID (low byte,
 * high byte) and bytes 1..7, alive counter 0..14 in the low nibble of byte 1 (AUTOSAR Profile 1
 * layout, data ID mode "both").
 *
 * Receive: ecu_frames_receive() checks a PlantSensors, PlantAnalog or Demand frame (a counter
 * step of 1 or 2 is OK: one lost frame before a good one is tolerated) and, when it is OK,
 * writes its values into the tick's inputs. Keep the "best" status per frame kind between ticks
 * (an OK since the last tick wins) and pass ECU_E2E_NONEWDATA for kinds that did not arrive.
 * Send: after ecu_tick, pack EcuActuator every tick, EcuStatus every 50 ms, EcuTelemetry
 * every tick (one of its ECU_TELEMETRY_COUNT multiplexed values per frame, round robin) and
 * EcuStarter every tick in ARMED and SHUTDOWN (the start/stop sequencer's starter and igniter),
 * each with the next alive counter and its CRC. Scheduling and the CAN driver are the
 * integrator's; ecu_node.h does all of this as the ECU's CAN node (the twin of ecu/node.py).
 */
#ifndef ECU_FRAMES_H
#define ECU_FRAMES_H

#include <stdint.h>

#include "ecu_core.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The frame IDs ECU_FRAME_DEMAND, _SENSORS, _ANALOG, _ACTUATOR, _STARTER, _STATUS, _TELEMETRY,
   their E2E data IDs and ECU_TELEMETRY_COUNT come from the DBC with the core's constants
   (generated/ecu_constants.h, included by ecu_core.h). */

typedef struct {
    int8_t rx_last[3];       /* last accepted alive counter: sensors, analog, demand (-1: none) */
    uint8_t tx_counter[4];   /* next alive counter: actuator, status, telemetry, starter */
    uint8_t telemetry_index; /* next EcuTelemetry multiplexer index */
} ecu_frames_t;

void ecu_frames_init(ecu_frames_t *f);

/* CRC-8 of a frame's bytes 1..7 under a data ID (as protocol/e2e.py). */
uint8_t ecu_e2e_crc(uint16_t data_id, const uint8_t data[8]);

/*
 * E2E check of one received frame (PlantSensors, PlantAnalog or Demand; its alive counter is
 * remembered unless REPEATED). Returns ECU_E2E_OK, _REPEATED, _WRONGSEQUENCE or _WRONGCRC, or -1
 * for a frame ID the ECU does not receive. ecu_frames_receive() and ecu_node.h build on it.
 */
int ecu_frames_check(ecu_frames_t *f, uint32_t frame_id, const uint8_t data[8]);

/*
 * Check one received frame and, when OK, unpack it into *in (Demand also sets *demand_tick, the
 * tick from which it applies). Returns ECU_E2E_OK, _REPEATED, _WRONGSEQUENCE or _WRONGCRC, or
 * -1 for a frame ID the ECU does not receive.
 */
int ecu_frames_receive(ecu_frames_t *f, uint32_t frame_id, const uint8_t data[8],
                       ecu_inputs_t *in, int32_t *demand_tick);

/* Pack the ECU's frames from the tick's outputs (telemetry also reads the observer state). */
void ecu_frames_actuator(ecu_frames_t *f, const ecu_outputs_t *o, uint8_t data[8]);
void ecu_frames_status(ecu_frames_t *f, const ecu_outputs_t *o, uint8_t data[8]);
void ecu_frames_telemetry(ecu_frames_t *f, const ecu_t *e, uint8_t data[8]);
void ecu_frames_starter(ecu_frames_t *f, const ecu_outputs_t *o, uint8_t data[8]);

#ifdef __cplusplus
}
#endif
#endif /* ECU_FRAMES_H */
