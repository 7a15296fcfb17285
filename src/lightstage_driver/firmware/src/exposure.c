#include "exposure.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#include "chain.h"
#include "clock.h"
#include "config.h"
#include "pins.h"

/* Exposures up to this many ticks end inside exposure_start() with interrupts disabled
 * (100 us: the UART's two-byte receive buffer holds ~170 us of input).  Longer ones end
 * in the compare-A interrupt, which is set EARLY_TICKS before the end and then polls the
 * counter up to the exact tick, so other interrupts' latency does not move the edge. */
#define SYNC_MAX_TICKS (100U * TICKS_PER_US)
#define EARLY_TICKS 64U
/* The rising edge goes this many ticks after the counter is read (16 us at 16 MHz): time
 * for the bookkeeping, which must not delay the edge. */
#define LEAD_TICKS 32U

enum { IDLE, RUNNING, FINISHED };

static volatile uint8_t state;
static volatile uint32_t end_ticks; /* 32-bit tick of the end */
static uint16_t end16;
static uint32_t trigger_us, end_us;

#define LATCH_BIT _BV(UNO_BIT(PIN_LATCH))
#define TRIGGER_BIT _BV(UNO_BIT(PIN_TRIGGER))

void exposure_init(void)
{
    PIN_LOW(PIN_TRIGGER);
    PIN_OUTPUT(PIN_TRIGGER);
    state = IDLE;
}

/* Busy-wait (interrupts disabled) until the low byte of TCNT1 reaches `target`; the
 * signed 8-bit difference keeps a late entry from waiting a whole 256-tick round. */
static inline void wait_until_lo(uint8_t target)
{
    while ((int8_t)(TCNT1L - target) < 0) {
    }
}

/* Trigger low and latch (the chain already holds zeros): the end of an exposure.  Called
 * at most SYNC_MAX_TICKS (or 2 * EARLY_TICKS plus interrupt latency) before the end. */
static inline void end_edges(void)
{
    uint16_t near = (uint16_t)(end16 - 32);
    while ((int16_t)(TCNT1 - near) < 0) {
    }
    uint8_t end_lo = (uint8_t)end16;
#if LATCH_TRIGGER_SAME_PORT
    uint8_t off = (uint8_t)((UNO_PORT_REG(PIN_TRIGGER) & ~TRIGGER_BIT) | LATCH_BIT);
    wait_until_lo(end_lo);
    UNO_PORT_REG(PIN_TRIGGER) = off;
#else
    wait_until_lo(end_lo);
    PIN_LOW(PIN_TRIGGER);
    PIN_HIGH(PIN_LATCH);
#endif
    PIN_LOW(PIN_LATCH);
}

void exposure_start(uint32_t word, uint32_t exposure_us)
{
    uint32_t exposure_ticks = exposure_us * TICKS_PER_US;
    /* Load the word now; it reaches the LEDs at the latch edge below. */
    chain_shift(word);

    uint8_t sreg = SREG;
    cli();
    /* All bookkeeping happens before the rising edge, for a start LEAD_TICKS ahead, so
     * that only the zero shift separates the two edges of the shortest exposure. */
    uint32_t ovf;
    uint16_t tcnt;
    clock_read_wide_unlocked(&ovf, &tcnt);
    uint16_t start16 = (uint16_t)(tcnt + LEAD_TICKS);
    if (start16 < tcnt)
        ovf++;
    trigger_us = clock_ticks_to_us(ovf, start16);
    end_us = trigger_us + exposure_us;
    end_ticks = ((ovf << 16) | start16) + exposure_ticks;
    end16 = (uint16_t)end_ticks;
    uint8_t start_lo = (uint8_t)start16;
#if LATCH_TRIGGER_SAME_PORT
    uint8_t on = (uint8_t)(UNO_PORT_REG(PIN_TRIGGER) | TRIGGER_BIT | LATCH_BIT);
    wait_until_lo(start_lo);
    UNO_PORT_REG(PIN_TRIGGER) = on;
#else
    wait_until_lo(start_lo);
    PIN_HIGH(PIN_LATCH);
    PIN_HIGH(PIN_TRIGGER);
#endif
    PIN_LOW(PIN_LATCH);

    /* The word after the exposure: all off. */
    chain_shift_zeros();

    if (exposure_ticks <= SYNC_MAX_TICKS) {
        end_edges();
        state = FINISHED;
    } else {
        OCR1A = (uint16_t)(end16 - EARLY_TICKS);
        TIFR1 = _BV(OCF1A);
        TIMSK1 |= _BV(OCIE1A);
        state = RUNNING;
    }
    SREG = sreg;
}

ISR(TIMER1_COMPA_vect)
{
    uint32_t ovf;
    uint16_t tcnt;
    clock_read_wide_unlocked(&ovf, &tcnt);
    int32_t left = (int32_t)(end_ticks - ((ovf << 16) | tcnt));
    if (left > (int32_t)(2 * EARLY_TICKS))
        return; /* matched a 65536-tick round early: the end is a later round */
    end_edges();
    TIMSK1 &= (uint8_t)~_BV(OCIE1A);
    state = FINISHED;
}

uint8_t exposure_running(void)
{
    return state == RUNNING;
}

uint8_t exposure_finished(void)
{
    return state == FINISHED;
}

uint8_t exposure_take_finished(uint32_t *t_trigger_us, uint32_t *t_end_us)
{
    if (state != FINISHED)
        return 0;
    *t_trigger_us = trigger_us;
    *t_end_us = end_us;
    state = IDLE;
    return 1;
}

void exposure_abort_all_off(void)
{
    uint8_t sreg = SREG;
    cli();
    TIMSK1 &= (uint8_t)~_BV(OCIE1A);
    PIN_LOW(PIN_TRIGGER);
    state = IDLE;
    SREG = sreg;
    chain_show(0);
}
