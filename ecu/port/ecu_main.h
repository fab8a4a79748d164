/*
 * ecu_main.h - the firmware image's main loop (ecu_main.c) and its calibration block.
 *
 * The calibration block is what the image reads from flash at start-up (board_calibration()):
 * little-endian, packed, checked before anything runs (ecu/port/pil.py writes it):
 *
 *   offset  size  field
 *        0     4  magic "ECUC"
 *        4     4  version (ECU_CAL_VERSION)
 *        8     4  flags: bit 0 lockstep (1: one tick per sensor frame, 0: the SysTick clock),
 *                 bit 1 profile (a console line per tick with its SysTick counts),
 *                 bit 2 XCP (the XCP slave, ecu_xcp.h, runs on the node)
 *       12     4  lockstep guard, ms: silence before ecu_node_timeout()
 *       16     4  watchdog timeout, ms (10..10000)
 *       20     4  n: parameter words (ECU_PARAM_WORDS)
 *       24    4n  the parameter words (ecu_params_load order)
 *    24+4n     4  XCP: the master's CAN ID (standard), master to ECU
 *    28+4n     4  XCP: the ECU's CAN ID, ECU to master
 *    32+4n     4  XCP: the seeds' generator start (non-zero)
 *    36+4n    4m  XCP: the run record (m = ECU_XCP_RUN_WORDS; ecu.port.xcp_run.run_record),
 *                 read in place by the slave
 * 36+4n+4m     4  CRC-32 (IEEE 802.3, as zlib.crc32) of the bytes before it
 *
 * A block that fails a check is refused: the image stays with the pump off, ticks nothing and
 * says why on the console ("CONFIG BAD <reason>").
 *
 * Console lines (board_console_write), each ending in "\n":
 *   "RESET watchdog"              this start-up followed a watchdog reset
 *   "CAL <counts> <instructions>" SysTick counts of a loop of known instruction count
 *   "CONFIG BAD <reason>"         the calibration block was refused
 *   "READY <rate_hz> <lockstep>"  running
 *   "K <node> <core>"             profile: SysTick counts of the node call that ran a tick and
 *                                 of its ecu_tick alone
 *   "WDTEST"                      the answer to the console command below
 *
 * Console commands (lines received): "WDTEST" stops the main loop without kicking the watchdog,
 * to prove on the bench that the watchdog resets the board (the pump output goes off first).
 */
#ifndef ECU_MAIN_H
#define ECU_MAIN_H

#include <stdint.h>

#define ECU_CAL_MAGIC 0x43554345u /* "ECUC" little-endian */
#define ECU_CAL_VERSION 2u
#define ECU_CAL_LOCKSTEP 1u
#define ECU_CAL_PROFILE 2u
#define ECU_CAL_XCP 4u
#define ECU_CAL_HEADER_BYTES 24u
#define ECU_CAL_XCP_BYTES 12u /* the XCP IDs and seed before the run record */

/* SysTick_Handler of the board's vector table calls this once per period. */
void ecu_main_systick(void);

/* Never returns. */
int main(void);

#endif /* ECU_MAIN_H */
