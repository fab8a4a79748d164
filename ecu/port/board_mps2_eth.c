/*
 * board_mps2_eth.c - the CAN link of the mps2-an386 board over its Ethernet controller (an SMSC
 * LAN9118 at 0x40200000, interrupt 13): one CAN frame per Ethernet frame.
 *
 * The frame: to the broadcast address, EtherType 0x88B5 (IEEE 802's local experimental type),
 * its payload the 16 bytes of Linux SocketCAN's struct can_frame (can_id little-endian with the
 * 29-bit flag in bit 31 and the remote flag in bit 30, the length, three reserved bytes, eight
 * data bytes), padded to Ethernet's 60-byte minimum. Frames of any other type are dropped. On
 * QEMU each Ethernet frame travels as one UDP datagram of its socket network backend, which
 * ecu/port/eth_can.py speaks on the host; on a real board the same frames would cross a cable to
 * a gateway. A whole CAN frame arrives with one interrupt, where the serial link takes one per
 * byte: this is the fast link of the processor-in-the-loop runs.
 *
 * Received frames are taken from the controller's receive FIFO in the interrupt into a static
 * queue; frames are sent from the main loop only.
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "board_mps2.h"

#define ETH_BASE 0x40200000u
#define ETH_REG(offset) (*(volatile uint32_t *)(ETH_BASE + (offset)))
#define RX_DATA_FIFO ETH_REG(0x00u)
#define TX_DATA_FIFO ETH_REG(0x20u)
#define RX_STATUS_FIFO ETH_REG(0x40u)
#define IRQ_CFG ETH_REG(0x54u)
#define INT_STS ETH_REG(0x58u)
#define INT_EN ETH_REG(0x5Cu)
#define BYTE_TEST ETH_REG(0x64u)
#define TX_CFG ETH_REG(0x70u)
#define HW_CFG ETH_REG(0x74u)
#define RX_FIFO_INF ETH_REG(0x7Cu)
#define TX_FIFO_INF ETH_REG(0x80u)
#define PMT_CTRL ETH_REG(0x84u)
#define MAC_CSR_CMD ETH_REG(0xA4u)
#define MAC_CSR_DATA ETH_REG(0xA8u)

#define BYTE_TEST_VALUE 0x87654321u
#define HW_CFG_SRST 1u
#define PMT_CTRL_READY 1u
#define IRQ_CFG_ACTIVE_HIGH_PUSH_PULL 0x111u /* IRQ_EN, IRQ_POL, IRQ_TYPE */
#define INT_RSFL 0x8u                        /* receive status FIFO above its level (0) */
#define TX_CFG_ON_SAO 0x6u                   /* transmitter on, status overrun allowed */
#define MAC_CSR_BUSY 0x80000000u
#define MAC_CSR_READ 0x40000000u
#define MAC_CR 1u
#define MAC_ADDRH 2u
#define MAC_ADDRL 3u
#define MAC_CR_TXEN_RXEN_FDPX 0x0010000Cu
#define RX_STATUS_ERROR 0x8000u
#define TX_CMD_A_FIRST_LAST 0x3000u
#define ETH_IRQ 13u

#define ETHERTYPE_CAN 0x88B5u
#define FRAME_BYTES 60u /* the Ethernet minimum without its FCS */
#define HEADER_BYTES 14u
#define CAN_FRAME_BYTES 16u /* struct can_frame */
#define CAN_EFF_FLAG 0x80000000u
#define CAN_RTR_FLAG 0x40000000u
#define CAN_EFF_MASK 0x1FFFFFFFu
#define RX_WORDS ((HEADER_BYTES + CAN_FRAME_BYTES + 3u) / 4u) /* the words a frame is read by */

#define QUEUE_SIZE 32u /* received frames; a power of two */

static struct {
    volatile uint32_t head, tail;
    board_can_rx_t f[QUEUE_SIZE];
} rx;
static volatile uint32_t rx_dropped; /* queue full, wrong type, errors */
static uint8_t mac[6];

void ETHERNET_Handler(void);

static void mac_write(uint32_t reg, uint32_t value)
{
    MAC_CSR_DATA = value;
    MAC_CSR_CMD = MAC_CSR_BUSY | reg;
    while (MAC_CSR_CMD & MAC_CSR_BUSY) {
    }
}

static uint32_t mac_read(uint32_t reg)
{
    MAC_CSR_CMD = MAC_CSR_BUSY | MAC_CSR_READ | reg;
    while (MAC_CSR_CMD & MAC_CSR_BUSY) {
    }
    return MAC_CSR_DATA;
}

void mps2_can_init(void)
{
    uint32_t low, high;
    if (BYTE_TEST != BYTE_TEST_VALUE) {
        return; /* no controller: nothing is received, sending waits for ever (watchdog) */
    }
    HW_CFG = HW_CFG_SRST;
    while ((HW_CFG & HW_CFG_SRST) || !(PMT_CTRL & PMT_CTRL_READY)) {
    }
    low = mac_read(MAC_ADDRL);
    high = mac_read(MAC_ADDRH);
    mac[0] = (uint8_t)low;
    mac[1] = (uint8_t)(low >> 8);
    mac[2] = (uint8_t)(low >> 16);
    mac[3] = (uint8_t)(low >> 24);
    mac[4] = (uint8_t)high;
    mac[5] = (uint8_t)(high >> 8);
    mac_write(MAC_CR, MAC_CR_TXEN_RXEN_FDPX); /* own address and broadcast */
    TX_CFG = TX_CFG_ON_SAO;
    INT_STS = 0xFFFFFFFFu;
    INT_EN = INT_RSFL;
    IRQ_CFG = IRQ_CFG_ACTIVE_HIGH_PUSH_PULL;
    NVIC_ISER0 = 1u << ETH_IRQ;
}

static uint32_t le32(const uint8_t *b)
{
    return (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
}

/* one received Ethernet frame (its first bytes in `b`, `len` with the FCS) into the queue */
static void take(const uint8_t *b, uint32_t len)
{
    const uint8_t *can = b + HEADER_BYTES;
    board_can_rx_t *f;
    uint32_t id;
    uint32_t k;
    if (len < HEADER_BYTES + CAN_FRAME_BYTES || ((uint32_t)b[12] << 8 | b[13]) != ETHERTYPE_CAN ||
        can[4] > 8u || rx.head - rx.tail >= QUEUE_SIZE) {
        rx_dropped++;
        return;
    }
    id = le32(can);
    f = &rx.f[rx.head & (QUEUE_SIZE - 1u)];
    f->extended = (uint8_t)((id & CAN_EFF_FLAG) != 0u);
    f->remote = (uint8_t)((id & CAN_RTR_FLAG) != 0u);
    f->id = id & (f->extended ? CAN_EFF_MASK : 0x7FFu);
    f->dlc = can[4];
    for (k = 0; k < 8u; k++) {
        f->data[k] = can[8u + k];
    }
    rx.head++;
}

void ETHERNET_Handler(void)
{
    uint32_t words[RX_WORDS];
    INT_STS = INT_RSFL; /* first: a frame coming after the loop raises it again */
    while ((RX_FIFO_INF >> 16) & 0xFFu) {
        uint32_t status = RX_STATUS_FIFO;
        uint32_t len = (status >> 16) & 0x3FFFu;
        uint32_t n = (len + 3u) / 4u;
        uint32_t k;
        for (k = 0; k < n; k++) {
            uint32_t w = RX_DATA_FIFO;
            if (k < RX_WORDS) {
                words[k] = w;
            }
        }
        if (status & RX_STATUS_ERROR) {
            rx_dropped++;
        } else {
            take((const uint8_t *)words, len);
        }
    }
}

int board_can_receive(board_can_rx_t *f)
{
    if (rx.head == rx.tail) {
        return 0;
    }
    *f = rx.f[rx.tail & (QUEUE_SIZE - 1u)];
    rx.tail++;
    return 1;
}

int board_can_pending(void)
{
    return rx.head != rx.tail;
}

void board_can_send(uint32_t id, const uint8_t *data, uint8_t dlc)
{
    uint32_t words[FRAME_BYTES / 4u] = {0u};
    uint8_t *b = (uint8_t *)words;
    uint32_t k;
    for (k = 0; k < 6u; k++) {
        b[k] = 0xFFu;
        b[6u + k] = mac[k];
    }
    b[12] = (uint8_t)(ETHERTYPE_CAN >> 8);
    b[13] = (uint8_t)ETHERTYPE_CAN;
    b[14] = (uint8_t)id;
    b[15] = (uint8_t)(id >> 8); /* standard 11-bit IDs: the upper bytes stay 0 */
    b[18] = dlc > 8u ? 8u : dlc;
    for (k = 0; k < b[18]; k++) {
        b[22u + k] = data[k];
    }
    while ((TX_FIFO_INF & 0xFFFFu) < FRAME_BYTES + 8u) {
        /* full: the controller drains it */
    }
    TX_DATA_FIFO = TX_CMD_A_FIRST_LAST | FRAME_BYTES;
    TX_DATA_FIFO = FRAME_BYTES; /* command B: tag 0, the frame's length */
    for (k = 0; k < FRAME_BYTES / 4u; k++) {
        TX_DATA_FIFO = words[k];
    }
}
