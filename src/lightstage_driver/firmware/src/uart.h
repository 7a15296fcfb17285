/* UART0 at 115200 8N1 with interrupt-driven receive and transmit rings. */
#ifndef LIGHTSTAGE_UART_H
#define LIGHTSTAGE_UART_H

#include <stdint.h>

void uart_init(void);
/* Next received byte; *after_gap is 1 when more than INTERBYTE_TIMEOUT_MS passed since the
 * byte before it (or bytes were lost before it).  Returns 0 when nothing is waiting. */
uint8_t uart_read(uint8_t *byte, uint8_t *after_gap);
/* Nonzero when a received byte is waiting. */
uint8_t uart_rx_pending(void);
/* Queue bytes for sending; waits (interrupts enabled) while the ring is full. */
void uart_write(const uint8_t *data, uint8_t length);
/* Nonzero while bytes remain to be sent. */
uint8_t uart_tx_busy(void);

#endif
