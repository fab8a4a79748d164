/*
 * board_mps2.c - the board layer (board.h) for QEMU's mps2-an386 (Cortex-M4, 25 MHz SYSCLK).
 *
 * - "CAN controller": UART0 (CMSDK APB UART) speaking slcan (Lawicel): frames from the host come
 *   as "tIIILDD..\r" lines and are acknowledged with "z\r"; the node's frames go out as such
 *   lines. O, C, L, S, s, F, Z, M, m, X, W, Q, U are answered with "\r" (F with "F00\r"), V with
 *   the version and N with the serial number; anything else with BEL. To the host the emulated
 *   MCU is a USB-CAN adapter (python-can's slcan interface, socket:// URL).
 * - console: UART1.
 * - both UARTs interrupt-driven with static ring buffers.
 * - watchdog: the CMSDK APB watchdog at 0x40008000 (first expiry: NMI, second: reset).
 * - calibration block: the 64 KiB flash sector at 0x000F0000 (mps2_an386_pil.ld).
 * - pump output: kept in a variable (the board has no PWM); reset handler: .data copied, .bss
 *   zeroed, then main().
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "ecu_main.h"

#define SYSCLK_HZ 25000000u

/* CMSDK APB UART */
typedef struct {
    volatile uint32_t data, state, ctrl, intstatus, bauddiv;
} uart_regs_t;
#define UART0 ((uart_regs_t *)0x40004000u)
#define UART1 ((uart_regs_t *)0x40005000u)
#define UART_STATE_TXFULL 1u
#define UART_STATE_RXFULL 2u
#define UART_CTRL_TX_EN 1u
#define UART_CTRL_RX_EN 2u
#define UART_CTRL_TX_INT 4u
#define UART_CTRL_RX_INT 8u
#define UART_INT_TX 1u
#define UART_INT_RX 2u

/* CMSDK APB watchdog */
#define WDOG_LOAD (*(volatile uint32_t *)0x40008000u)
#define WDOG_CTRL (*(volatile uint32_t *)0x40008008u)
#define WDOG_INTCLR (*(volatile uint32_t *)0x4000800Cu)
#define WDOG_LOCK (*(volatile uint32_t *)0x40008C00u)
#define WDOG_UNLOCK_KEY 0x1ACCE551u

/* NVIC */
#define NVIC_ISER0 (*(volatile uint32_t *)0xE000E100u)

#define WATCHDOG_MARK 0x474F4457u /* "WDOG": left in .noinit by the NMI before the reset */

/* a single-producer single-consumer byte queue (one side in an interrupt) */
#define RING_SIZE 1024u /* a power of two */
typedef struct {
    volatile uint32_t head, tail; /* head: next write, tail: next read (free-running) */
    uint8_t b[RING_SIZE];
} ring_t;

static int ring_put(ring_t *r, uint8_t c)
{
    if (r->head - r->tail >= RING_SIZE) {
        return 0;
    }
    r->b[r->head & (RING_SIZE - 1u)] = c;
    r->head++;
    return 1;
}

static int ring_get(ring_t *r, uint8_t *c)
{
    if (r->head == r->tail) {
        return 0;
    }
    *c = r->b[r->tail & (RING_SIZE - 1u)];
    r->tail++;
    return 1;
}

typedef struct {
    uart_regs_t *regs;
    ring_t rx, tx;
    volatile uint8_t tx_active;
    volatile uint32_t rx_dropped;
} uart_t;

static uart_t can_uart, console_uart;
static uint32_t watchdog_mark __attribute__((section(".noinit")));
static int watchdog_reset;
static int32_t pump_duty_cpct, pump_enable; /* what a PWM driver would take */

/* slcan receive state */
static char line[40];
static size_t line_len;
static int line_overflow;

static void irq_disable(void)
{
    __asm__ volatile("cpsid i" ::: "memory");
}

static void irq_enable(void)
{
    __asm__ volatile("cpsie i" ::: "memory");
}

static void uart_init(uart_t *u, uart_regs_t *regs, uint32_t ctrl)
{
    u->regs = regs;
    regs->bauddiv = SYSCLK_HZ / 115200u;
    regs->intstatus = UART_INT_TX | UART_INT_RX;
    regs->ctrl = ctrl;
}

static void uart_rx_isr(uart_t *u)
{
    u->regs->intstatus = UART_INT_RX; /* first: a byte coming after the loop raises it again */
    while (u->regs->state & UART_STATE_RXFULL) {
        if (!ring_put(&u->rx, (uint8_t)u->regs->data)) {
            u->rx_dropped++;
        }
    }
}

static void uart_tx_isr(uart_t *u)
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

static void uart_write(uart_t *u, const char *s, size_t n)
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

void UART0_RX_Handler(void);
void UART0_TX_Handler(void);
void UART1_RX_Handler(void);
void UART1_TX_Handler(void);
void SysTick_Handler(void);
void NMI_Handler(void);
void HardFault_Handler(void);
void Default_Handler(void);
void Reset_Handler(void);

void UART0_RX_Handler(void)
{
    uart_rx_isr(&can_uart);
}

void UART0_TX_Handler(void)
{
    uart_tx_isr(&can_uart);
}

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
    uart_init(&can_uart, UART0,
              UART_CTRL_TX_EN | UART_CTRL_RX_EN | UART_CTRL_TX_INT | UART_CTRL_RX_INT);
    uart_init(&console_uart, UART1,
              UART_CTRL_TX_EN | UART_CTRL_RX_EN | UART_CTRL_TX_INT | UART_CTRL_RX_INT);
    NVIC_ISER0 = 0xFu; /* IRQ 0..3: UART0 RX, TX, UART1 RX, TX */
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

static void can_reply(const char *s)
{
    size_t n = 0;
    while (s[n] != '\0') {
        n++;
    }
    uart_write(&can_uart, s, n);
}

static int hex_digit(char c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    return -1;
}

/* n hex digits of s as a number, or -1 */
static int32_t hex_value(const char *s, size_t n)
{
    int32_t v = 0;
    size_t k;
    for (k = 0; k < n; k++) {
        int d = hex_digit(s[k]);
        if (d < 0) {
            return -1;
        }
        v = v * 16 + d;
    }
    return v;
}

/* one frame line ("t", "T", "r", "R"); 1 and *f filled, or 0 when malformed */
static int parse_frame(const char *s, size_t n, board_can_rx_t *f)
{
    size_t width = (s[0] == 'T' || s[0] == 'R') ? 8u : 3u;
    int32_t id, dlc, byte;
    size_t k;
    if (n < 2u + width) {
        return 0;
    }
    if (width == 8u && hex_digit(s[1]) > 1) {
        return 0; /* over 29 bits (and the int32 below) */
    }
    id = hex_value(s + 1, width);
    dlc = hex_value(s + 1 + width, 1u);
    if (id < 0 || (width == 3u && id > 0x7FF) || dlc < 0 || dlc > 8) {
        return 0;
    }
    f->extended = (uint8_t)(width == 8u);
    f->remote = (uint8_t)(s[0] == 'r' || s[0] == 'R');
    f->id = (uint32_t)id;
    f->dlc = (uint8_t)dlc;
    if (f->remote) {
        return n == 2u + width;
    }
    if (n != 2u + width + 2u * (size_t)dlc) {
        return 0;
    }
    for (k = 0; k < (size_t)dlc; k++) {
        byte = hex_value(s + 2 + width + 2u * k, 2u);
        if (byte < 0) {
            return 0;
        }
        f->data[k] = (uint8_t)byte;
    }
    return 1;
}

/* one complete line: 1 when it was a frame (in *f), else 0 (a command, answered here) */
static int slcan_line(const char *s, size_t n, board_can_rx_t *f)
{
    if (n == 0u) {
        return 0; /* an empty line: nothing to answer */
    }
    switch (s[0]) {
    case 't':
    case 'T':
    case 'r':
    case 'R':
        if (!parse_frame(s, n, f)) {
            can_reply("\a");
            return 0;
        }
        can_reply(f->extended ? "Z\r" : "z\r");
        return 1;
    case 'V':
        can_reply("V1013\r");
        return 0;
    case 'N':
        can_reply("NPIL1\r");
        return 0;
    case 'F':
        can_reply("F00\r");
        return 0;
    case 'O':
    case 'C':
    case 'L':
    case 'S':
    case 's':
    case 'Z':
    case 'M':
    case 'm':
    case 'X':
    case 'W':
    case 'Q':
    case 'U':
        can_reply("\r");
        return 0;
    default:
        can_reply("\a");
        return 0;
    }
}

int board_can_receive(board_can_rx_t *f)
{
    uint8_t c;
    while (ring_get(&can_uart.rx, &c)) {
        if (c == '\r' || c == '\n') {
            int got = 0;
            if (line_overflow) {
                can_reply("\a");
            } else {
                got = slcan_line(line, line_len, f);
            }
            line_len = 0u;
            line_overflow = 0;
            if (got) {
                return 1;
            }
        } else if (line_len < sizeof line) {
            line[line_len++] = (char)c;
        } else {
            line_overflow = 1;
        }
    }
    return 0;
}

int board_can_pending(void)
{
    return can_uart.rx.head != can_uart.rx.tail || line_len != 0u;
}

void board_can_send(const ecu_can_frame_t *f)
{
    static const char digits[] = "0123456789ABCDEF";
    char s[22]; /* "tIIIL" + 16 digits + CR */
    size_t k;
    s[0] = 't';
    s[1] = digits[(f->id >> 8) & 0x7u];
    s[2] = digits[(f->id >> 4) & 0xFu];
    s[3] = digits[f->id & 0xFu];
    s[4] = '8';
    for (k = 0; k < 8u; k++) {
        s[5 + 2 * k] = digits[f->data[k] >> 4];
        s[6 + 2 * k] = digits[f->data[k] & 0xFu];
    }
    s[21] = '\r';
    uart_write(&can_uart, s, sizeof s);
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
