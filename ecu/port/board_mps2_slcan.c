/*
 * board_mps2_slcan.c - the CAN link of the mps2-an386 board over UART0, speaking slcan
 * (Lawicel): frames from the host come as "tIIILDD..\r" lines and are acknowledged with "z\r";
 * the node's frames go out as such lines. O, C, L, S, s, F, Z, M, m, X, W, Q, U are answered
 * with "\r" (F with "F00\r"), V with the version and N with the serial number; anything else
 * with BEL. To the host the emulated MCU is a USB-CAN adapter (python-can's slcan interface,
 * socket:// URL). The UART is interrupt-driven with static ring buffers.
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "board_mps2.h"

#define UART0 ((uart_regs_t *)0x40004000u)

static uart_t can_uart;

/* slcan receive state */
static char line[40];
static size_t line_len;
static int line_overflow;

void UART0_RX_Handler(void);
void UART0_TX_Handler(void);

void UART0_RX_Handler(void)
{
    uart_rx_isr(&can_uart);
}

void UART0_TX_Handler(void)
{
    uart_tx_isr(&can_uart);
}

void mps2_can_init(void)
{
    uart_init(&can_uart, UART0);
    NVIC_ISER0 = 0x3u; /* IRQ 0, 1: UART0 RX, TX */
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

void board_can_send(uint32_t id, const uint8_t *data, uint8_t dlc)
{
    static const char digits[] = "0123456789ABCDEF";
    char s[22]; /* "tIIIL" + up to 16 digits + CR */
    size_t k, n = dlc > 8u ? 8u : dlc;
    s[0] = 't';
    s[1] = digits[(id >> 8) & 0x7u];
    s[2] = digits[(id >> 4) & 0xFu];
    s[3] = digits[id & 0xFu];
    s[4] = digits[n];
    for (k = 0; k < n; k++) {
        s[5 + 2 * k] = digits[data[k] >> 4];
        s[6 + 2 * k] = digits[data[k] & 0xFu];
    }
    s[5 + 2 * n] = '\r';
    uart_write(&can_uart, s, 6 + 2 * n);
}
