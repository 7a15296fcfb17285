#include "link.h"

#include <util/crc16.h>

#include "uart.h"

enum { HUNT, LEN, SEQ, CMD, PAYLOAD, CRC_LO, CRC_HI };

static uint8_t rx_state = HUNT;
static uint8_t rx_index;
static uint16_t rx_crc, rx_crc_received;
static uint16_t rx_errors;

static void count_error(void)
{
    if (rx_errors != 0xFFFF)
        rx_errors++;
}

uint16_t link_rx_errors(void)
{
    return rx_errors;
}

uint8_t link_poll(frame_t *f, uint16_t *crc_received)
{
    uint8_t b, gap;
    while (uart_read(&b, &gap)) {
        if (gap && rx_state != HUNT) {
            /* inter-byte timeout: drop the partial frame, this byte may start the next */
            count_error();
            rx_state = HUNT;
        }
        switch (rx_state) {
        case HUNT:
            if (b == SOF) {
                rx_state = LEN;
                rx_crc = 0xFFFF;
            }
            break;
        case LEN:
            if (b > MAX_PAYLOAD) {
                count_error();
                rx_state = (b == SOF) ? LEN : HUNT;
                break;
            }
            f->len = b;
            rx_crc = _crc_xmodem_update(rx_crc, b);
            rx_state = SEQ;
            break;
        case SEQ:
            f->seq = b;
            rx_crc = _crc_xmodem_update(rx_crc, b);
            rx_state = CMD;
            break;
        case CMD:
            f->cmd = b;
            rx_crc = _crc_xmodem_update(rx_crc, b);
            rx_index = 0;
            rx_state = f->len ? PAYLOAD : CRC_LO;
            break;
        case PAYLOAD:
            f->payload[rx_index++] = b;
            rx_crc = _crc_xmodem_update(rx_crc, b);
            if (rx_index == f->len)
                rx_state = CRC_LO;
            break;
        case CRC_LO:
            rx_crc_received = b;
            rx_state = CRC_HI;
            break;
        case CRC_HI:
            rx_crc_received |= (uint16_t)b << 8;
            rx_state = HUNT;
            if (rx_crc_received == rx_crc)
                return LINK_FRAME;
            count_error();
            *crc_received = rx_crc_received;
            return LINK_BAD_CRC;
        }
    }
    return LINK_NOTHING;
}

void link_send(uint8_t seq, uint8_t cmd, const uint8_t *payload, uint8_t len)
{
    uint8_t head[4] = {SOF, len, seq, cmd};
    uint16_t crc = 0xFFFF;
    for (uint8_t i = 1; i < 4; i++)
        crc = _crc_xmodem_update(crc, head[i]);
    for (uint8_t i = 0; i < len; i++)
        crc = _crc_xmodem_update(crc, payload[i]);
    uint8_t tail[2] = {(uint8_t)crc, (uint8_t)(crc >> 8)};
    uart_write(head, 4);
    uart_write(payload, len);
    uart_write(tail, 2);
}
