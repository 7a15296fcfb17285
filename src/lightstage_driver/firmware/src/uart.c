#include "uart.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "clock.h"
#include "config.h"

#define RX_SIZE 128 /* power of two */
#define TX_SIZE 128 /* power of two */

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_gap[RX_SIZE / 8]; /* one "after a gap" bit per slot */
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t rx_lost; /* a byte was dropped: flag the next stored one */
static volatile uint32_t rx_last_ms;

static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;

void uart_init(void)
{
    /* 115200 at 16 MHz: U2X, UBRR = 16 (2.1 % error, as the Arduino core). */
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)((F_CPU / (8UL * BAUD)) - 1);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

ISR(USART_RX_vect)
{
    uint8_t status = UCSR0A;
    uint8_t byte = UDR0;
    uint32_t now = clock_ms();
    uint8_t gap = rx_lost || (status & (_BV(FE0) | _BV(DOR0))) ||
                  (now - rx_last_ms) > INTERBYTE_TIMEOUT_MS;
    rx_last_ms = now;
    uint8_t next = (rx_head + 1) & (RX_SIZE - 1);
    if (next == rx_tail) {
        rx_lost = 1;
        return;
    }
    rx_buf[rx_head] = byte;
    if (gap)
        rx_gap[rx_head >> 3] |= (uint8_t)_BV(rx_head & 7);
    else
        rx_gap[rx_head >> 3] &= (uint8_t)~_BV(rx_head & 7);
    rx_head = next;
    rx_lost = 0;
}

uint8_t uart_read(uint8_t *byte, uint8_t *after_gap)
{
    uint8_t tail = rx_tail;
    if (tail == rx_head)
        return 0;
    *byte = rx_buf[tail];
    *after_gap = (rx_gap[tail >> 3] >> (tail & 7)) & 1;
    rx_tail = (tail + 1) & (RX_SIZE - 1);
    return 1;
}

uint8_t uart_rx_pending(void)
{
    return rx_tail != rx_head;
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (tx_tail + 1) & (TX_SIZE - 1);
}

void uart_write(const uint8_t *data, uint8_t length)
{
    for (uint8_t i = 0; i < length; i++) {
        uint8_t next = (tx_head + 1) & (TX_SIZE - 1);
        while (next == tx_tail) {
            /* ring full: the UDRE interrupt drains it */
        }
        tx_buf[tx_head] = data[i];
        tx_head = next;
        UCSR0B |= _BV(UDRIE0);
    }
}

uint8_t uart_tx_busy(void)
{
    return tx_head != tx_tail;
}
