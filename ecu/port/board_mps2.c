/*
 * board_mps2.c - the board layer (board.h) for QEMU's mps2-an386 (Cortex-M4, 25 MHz SYSCLK):
 * what every image on it shares. Its CAN link is one of:
 *
 * - board_mps2_slcan.c: UART0 speaking slcan (Lawicel), so that the emulated MCU looks like a
 *   USB-CAN adapter to the host (python-can's slcan interface, socket:// URL);
 * - board_mps2_eth.c: the LAN9118 Ethernet controller carrying one CAN frame per Ethernet frame
 *   (ecu/port/eth_can.py on the host, over QEMU's UDP socket network backend).
 *
 * Here: the console on UART1 (interrupt-driven, static ring buffers), the watchdog (the CMSDK
 * APB watchdog at 0x40008000: first expiry NMI, second reset), the calibration block (the
 * 64 KiB flash sector at 0x000F0000, mps2_an386_pil.ld), the pump output (kept in a variable:
 * the board has no PWM) and the reset handler (.data copied, .bss zeroed, then main()).
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "board_mps2.h"
#include "ecu_main.h"

#define UART1 ((uart_regs_t *)0x40005000u)

/* CMSDK APB watchdog */
#define WDOG_LOAD (*(volatile uint32_t *)0x40008000u)
#define WDOG_CTRL (*(volatile uint32_t *)0x40008008u)
#define WDOG_INTCLR (*(volatile uint32_t *)0x4000800Cu)
#define WDOG_LOCK (*(volatile uint32_t *)0x40008C00u)
#define WDOG_UNLOCK_KEY 0x1ACCE551u

#define WATCHDOG_MARK 0x474F4457u /* "WDOG": left in .noinit by the NMI before the reset */

static uart_t console_uart;
static uint32_t watchdog_mark __attribute__((section(".noinit")));
static int watchdog_reset;
static int32_t pump_duty_cpct, pump_enable; /* what a PWM driver would take */

static int ring_put(ring_t *r, uint8_t c)
{
    if (r->head - r->tail >= RING_SIZE) {
        return 0;
    }
    r->b[r->head & (RING_SIZE - 1u)] = c;
    r->head++;
    return 1;
}

int ring_get(ring_t *r, uint8_t *c)
{
    if (r->head == r->tail) {
        return 0;
    }
    *c = r->b[r->tail & (RING_SIZE - 1u)];
    r->tail++;
    return 1;
}

void uart_init(uart_t *u, uart_regs_t *regs)
{
    u->regs = regs;
    regs->bauddiv = SYSCLK_HZ / 115200u;
    regs->intstatus = UART_INT_TX | UART_INT_RX;
    regs->ctrl = UART_CTRL_ALL;
}

void uart_rx_isr(uart_t *u)
{
    u->regs->intstatus = UART_INT_RX; /* first: a byte coming after the loop raises it again */
    while (u->regs->state & UART_STATE_RXFULL) {
        if (!ring_put(&u->rx, (uint8_t)u->regs->data)) {
            u->rx_dropped++;
        }
    }
}

void uart_tx_isr(uart_t *u)
{
    uint8_t c;
    u->regs->intstatus = UART_INT_TX;
    if (!(u->regs->state & UART_STATE_TXFULL)) {
        if (ring_get(&u->tx, &c)) {
            u->regs->data = c;
        } else {
            u->tx_active = 0u;
        }
    }
}

void uart_write(uart_t *u, const char *s, size_t n)
{
    size_t k;
    uint8_t c;
    for (k = 0; k < n; k++) {
        while (!ring_put(&u->tx, (uint8_t)s[k])) {
            /* full: the transmit interrupt drains it */
        }
    }
    irq_disable();
    if (!u->tx_active && ring_get(&u->tx, &c)) {
        u->tx_active = 1u;
        u->regs->data = c;
    }
    irq_enable();
}

void UART1_RX_Handler(void);
void UART1_TX_Handler(void);
void SysTick_Handler(void);
void NMI_Handler(void);
void HardFault_Handler(void);
void Default_Handler(void);
void Reset_Handler(void);

void UART1_RX_Handler(void)
{
    uart_rx_isr(&console_uart);
}

void UART1_TX_Handler(void)
{
    uart_tx_isr(&console_uart);
}

void SysTick_Handler(void)
{
    ecu_main_systick();
}

void NMI_Handler(void) /* the watchdog's first expiry: the reset follows */
{
    watchdog_mark = WATCHDOG_MARK;
    for (;;) {
    }
}

void HardFault_Handler(void)
{
    for (;;) { /* the watchdog resets the board */
    }
}

void Default_Handler(void)
{
    for (;;) {
    }
}

/* the handlers of the link not linked into this image */
void UART0_RX_Handler(void) __attribute__((weak, alias("Default_Handler")));
void UART0_TX_Handler(void) __attribute__((weak, alias("Default_Handler")));
void ETHERNET_Handler(void) __attribute__((weak, alias("Default_Handler")));

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss;
extern const uint8_t __calib_start[], __calib_end[];

void Reset_Handler(void)
{
    uint32_t *src = &_sidata, *dst = &_sdata;
    while (dst < &_edata) {
        *dst++ = *src++;
    }
    for (dst = &_sbss; dst < &_ebss; dst++) {
        *dst = 0u;
    }
    main();
    for (;;) {
    }
}

void board_init(void)
{
    watchdog_reset = watchdog_mark == WATCHDOG_MARK;
    watchdog_mark = 0u;
    uart_init(&console_uart, UART1);
    NVIC_ISER0 = 0xCu; /* IRQ 2, 3: UART1 RX, TX */
    mps2_can_init();
    irq_enable();
}

uint32_t board_core_hz(void)
{
    return SYSCLK_HZ;
}

int board_reset_by_watchdog(void)
{
    return watchdog_reset;
}

const uint8_t *board_calibration(size_t *len)
{
    *len = (size_t)(__calib_end - __calib_start);
    return __calib_start;
}

void board_pump_output(int32_t duty_cpct, int32_t enable)
{
    pump_duty_cpct = duty_cpct;
    pump_enable = enable;
}

void board_watchdog_start(uint32_t timeout_ms)
{
    WDOG_LOCK = WDOG_UNLOCK_KEY;
    WDOG_LOAD = SYSCLK_HZ / 1000u * timeout_ms / 2u; /* NMI at half, reset at the timeout */
    WDOG_CTRL = 3u;                                    /* interrupt and reset enabled */
    WDOG_LOCK = 0u;
}

void board_watchdog_kick(void)
{
    WDOG_LOCK = WDOG_UNLOCK_KEY;
    WDOG_INTCLR = 1u; /* clears the interrupt and reloads the counter */
    WDOG_LOCK = 0u;
}

void board_console_write(const char *s, size_t n)
{
    uart_write(&console_uart, s, n);
}

int board_console_read(char *c)
{
    uint8_t b;
    if (!ring_get(&console_uart.rx, &b)) {
        return 0;
    }
    *c = (char)b;
    return 1;
}
