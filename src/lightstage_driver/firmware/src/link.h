/* Frames of protocol v1 (docs/PROTOCOL.md): SOF, LEN, SEQ, CMD, PAYLOAD, CRC-16/CCITT-FALSE
 * little-endian over LEN..PAYLOAD. */
#ifndef LIGHTSTAGE_LINK_H
#define LIGHTSTAGE_LINK_H

#include <stdint.h>

#include "config.h"

#define SOF 0xA5

typedef struct {
    uint8_t len, seq, cmd;
    uint8_t payload[MAX_PAYLOAD];
} frame_t;

enum { LINK_NOTHING = 0, LINK_FRAME, LINK_BAD_CRC };

/* Feed received bytes to the frame receiver until a frame is complete or nothing is
 * left.  LINK_BAD_CRC fills seq/cmd as received and *crc_received. */
uint8_t link_poll(frame_t *frame, uint16_t *crc_received);
/* Frames dropped by the receiver since reset (CRC, length, inter-byte timeout),
 * saturating at 65535. */
uint16_t link_rx_errors(void);
void link_send(uint8_t seq, uint8_t cmd, const uint8_t *payload, uint8_t len);

#endif
