/*
 * board_mps2.h - what the parts of the mps2-an386 board share (board_mps2.c and its CAN links,
 * board_mps2_slcan.c or board_mps2_eth.c: one of them is linked into an image).
 */
#ifndef BOARD_MPS2_H
#define BOARD_MPS2_H

#include <stddef.h>
#include <stdint.h>

#define SYSCLK_HZ 25000000u

/* NVIC */
#define NVIC_ISER0 (*(volatile uint32_t *)0xE000E100u)

/* CMSDK APB UART */
typedef struct {
    volatile uint32_t data, state, ctrl, intstatus, bauddiv;
} uart_regs_t;
#define UART_STATE_TXFULL 1u
#define UART_STATE_RXFULL 2u
#define UART_CTRL_ALL 15u /* TX and RX enabled, their interrupts too */
#define UART_INT_TX 1u
#define UART_INT_RX 2u

/* a single-producer single-consumer byte queue (one side in an interrupt) */
#define RING_SIZE 1024u /* a power of two */
typedef struct {
    volatile uint32_t head, tail; /* head: next write, tail: next read (free-running) */
    uint8_t b[RING_SIZE];
} ring_t;

typedef struct {
    uart_regs_t *regs;
    ring_t rx, tx;
    volatile uint8_t tx_active;
    volatile uint32_t rx_dropped;
} uart_t;

static inline void irq_disable(void)
{
    __asm__ volatile("cpsid i" ::: "memory");
}

static inline void irq_enable(void)
{
    __asm__ volatile("cpsie i" ::: "memory");
}

int ring_get(ring_t *r, uint8_t *c);
void uart_init(uart_t *u, uart_regs_t *regs);
void uart_rx_isr(uart_t *u);
void uart_tx_isr(uart_t *u);
void uart_write(uart_t *u, const char *s, size_t n);

/* The CAN link's start-up (its controller, its interrupts enabled in the NVIC), from
   board_init() with interrupts still masked. */
void mps2_can_init(void);

#endif /* BOARD_MPS2_H */
