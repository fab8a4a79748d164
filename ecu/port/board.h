/*
 * board.h - what the firmware's main loop (ecu_main.c) needs from a board.
 *
 * ecu_main.c is the reference integration of the ECU on a Cortex-M: the SysTick timer at the
 * ECU rate, the CAN node (ecu_node.h) and the control core (ecu_core.h), the watchdog, no heap.
 * Everything specific to a board is behind the functions below. To run the firmware on your
 * board, write board_<yours>.c with:
 *
 *   - its clocks and pins (board_init, board_core_hz),
 *   - its CAN controller, interrupt-driven into a receive queue (board_can_receive,
 *     board_can_pending, board_can_send),
 *   - where its calibration block lies in flash (board_calibration),
 *   - its pump driver output (board_pump_output), its watchdog (board_watchdog_start,
 *     board_watchdog_kick) and a debug console (board_console_write, board_console_read).
 *
 * board_mps2.c is the board for QEMU's mps2-an386 (Cortex-M4), with one of two CAN links:
 * board_mps2_eth.c (its Ethernet controller, one CAN frame per Ethernet frame) or
 * board_mps2_slcan.c (UART0 speaking slcan, so that the emulated MCU looks like a USB-CAN
 * adapter to the host); its console is UART1. Interrupt handlers of a board call nothing of
 * ecu_main.c but ecu_main_systick() (from SysTick_Handler, if the board owns the vector table).
 */
#ifndef BOARD_H
#define BOARD_H

#include <stddef.h>
#include <stdint.h>

#include "ecu_node.h"

/* a received CAN frame: the node takes standard-ID data frames (of 8 bytes but XCP's) */
typedef struct {
    uint32_t id;
    uint8_t extended; /* 1: 29-bit ID */
    uint8_t remote;   /* 1: remote frame */
    uint8_t dlc;      /* data length, 0..8 */
    uint8_t data[8];
} board_can_rx_t;

/* Clocks, pins, the CAN controller and the console, their interrupts enabled; not SysTick. */
void board_init(void);

/* The SysTick clock in Hz (the core clock on a real part). */
uint32_t board_core_hz(void);

/* The calibration block (ecu_main.h: ECU_CAL_*) as stored in flash; *len: its size in bytes. */
const uint8_t *board_calibration(size_t *len);

/* Take the oldest received frame: 1 and *f filled, or 0 when none is queued. */
int board_can_receive(board_can_rx_t *f);

/* 1 when a received frame (or part of one, on a serial CAN link) waits; called with interrupts
   disabled, right before the main loop sleeps. */
int board_can_pending(void);

/* Queue a standard-ID data frame of dlc bytes (0..8) for sending, in call order; waits only
   while the transmit queue is full. */
void board_can_send(uint32_t id, const uint8_t *data, uint8_t dlc);

/* The pump driver: PWM duty in 0.01 % (0..10000) and its enable, after every tick. */
void board_pump_output(int32_t duty_cpct, int32_t enable);

/* Start the watchdog: the board resets unless board_watchdog_kick() comes within timeout_ms. */
void board_watchdog_start(uint32_t timeout_ms);
void board_watchdog_kick(void);

/* 1 when this start-up is a watchdog reset (read once after board_init). */
int board_reset_by_watchdog(void);

/* The debug console: n bytes, queued (waits only while its queue is full). */
void board_console_write(const char *s, size_t n);

/* The debug console's input: 1 and *c the oldest byte received, or 0 when none. */
int board_console_read(char *c);

#endif /* BOARD_H */
