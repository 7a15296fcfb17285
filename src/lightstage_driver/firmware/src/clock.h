/* Free-running time base on Timer1 (F_CPU/8 ticks, extended to 32 bits by the overflow
 * interrupt) and a 1 kHz wake-up tick on compare channel B. */
#ifndef LIGHTSTAGE_CLOCK_H
#define LIGHTSTAGE_CLOCK_H

#include <stdint.h>

void clock_init(void);
/* 32-bit tick count (wraps every 2^32 ticks = 35.8 min at 0.5 us); safe with or without
 * interrupts enabled. */
uint32_t clock_ticks(void);
/* Microseconds since reset modulo 2^32 (the protocol's t_us). */
uint32_t clock_us(void);
/* t_us of a tick count taken with clock_ticks_wide(). */
uint32_t clock_ticks_to_us(uint32_t overflows, uint16_t tcnt);
/* Milliseconds since reset (from the 1 kHz tick). */
uint32_t clock_ms(void);

/* Overflow count and counter, read consistently (interrupts must be disabled). */
void clock_read_wide_unlocked(uint32_t *overflows, uint16_t *tcnt);

#endif
