#include "clock.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "config.h"

#define TICKS_PER_MS (1000U * TICKS_PER_US)

static volatile uint32_t overflows;
static volatile uint32_t millis;

void clock_init(void)
{
    TCCR1A = 0;
    TCCR1B = 0;
    TCNT1 = 0;
    OCR1B = TICKS_PER_MS;
    TIFR1 = _BV(TOV1) | _BV(OCF1A) | _BV(OCF1B);
    TIMSK1 = _BV(TOIE1) | _BV(OCIE1B);
    TCCR1B = TIMER1_PRESCALER_BITS; /* normal mode, free running */
}

ISR(TIMER1_OVF_vect)
{
    overflows++;
}

ISR(TIMER1_COMPB_vect)
{
    OCR1B += TICKS_PER_MS;
    millis++;
}

void clock_read_wide_unlocked(uint32_t *ovf, uint16_t *tcnt)
{
    uint16_t t = TCNT1;
    uint32_t o = overflows;
    /* An overflow that happened after interrupts were disabled is still pending. */
    if ((TIFR1 & _BV(TOV1)) && t < 0x8000)
        o++;
    *ovf = o;
    *tcnt = t;
}

uint32_t clock_ticks(void)
{
    uint32_t o;
    uint16_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        clock_read_wide_unlocked(&o, &t);
    }
    return (o << 16) | t;
}

uint32_t clock_ticks_to_us(uint32_t ovf, uint16_t tcnt)
{
    /* ticks / 2 with ticks = ovf * 65536 + tcnt, modulo 2^32 */
    return (ovf << 15) + (tcnt >> 1);
}

uint32_t clock_us(void)
{
    uint32_t o;
    uint16_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        clock_read_wide_unlocked(&o, &t);
    }
    return clock_ticks_to_us(o, t);
}

uint32_t clock_ms(void)
{
    uint32_t m;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        m = millis;
    }
    return m;
}
