#include "exposure.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#include "chain.h"
#include "clock.h"
#include "config.h"
#include "pins.h"
#include "schedule.h"

/* Exposures up to this many ticks end inside exposure_start() with interrupts disabled
 * (100 us: the UART's two-byte receive buffer holds ~170 us of input).  In longer ones each
 * edge (a graded step or the end) is latched in the compare-A interrupt, which is set
 * EARLY_TICKS before it and then polls the counter up to the exact tick, so other
 * interrupts' latency does not move the edge; edges closer than 2 * EARLY_TICKS follow in
 * the same interrupt. */
#define SYNC_MAX_TICKS (100U * TICKS_PER_US)
#define EARLY_TICKS 64U
/* The rising edge goes this many ticks after the counter is read (16 us at 16 MHz): time
 * for the bookkeeping, which must not delay the edge. */
#define LEAD_TICKS 32U

enum { IDLE, RUNNING, FINISHED };

static volatile uint8_t state;
static schedule_t schedule;
static uint8_t next_step;           /* the step the chain holds the word of */
static uint32_t start_ticks;        /* 32-bit tick of the rising edge */
static uint32_t end_ticks;          /* 32-bit tick of the end */
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

/* Busy-wait (interrupts disabled) until the tick whose low 16 bits are `at16`, at most
 * 32767 ticks ahead, exactly: the 16-bit counter gets near, its low byte the rest. */
static inline void wait_until(uint16_t at16)
{
    uint16_t near = (uint16_t)(at16 - 32);
    while ((int16_t)(TCNT1 - near) < 0) {
    }
    wait_until_lo((uint8_t)at16);
}

/* The tick of the next edge: the step the chain holds, or the end. */
static uint32_t next_edge(void)
{
    return next_step < schedule.steps ? start_ticks + schedule.at[next_step] : end_ticks;
}

/* Load the chain with what the next edge latches: a step's word, or zeros for the end. */
static void shift_next(void)
{
    if (next_step < schedule.steps)
        chain_shift(schedule.word[next_step]);
    else
        chain_shift_zeros();
}

/* Trigger low and latch (the chain already holds zeros): the end of an exposure. */
static inline void end_edges(void)
{
    uint16_t end16 = (uint16_t)end_ticks;
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

/* Latch every edge due within `window` ticks (interrupts disabled), each on its exact
 * tick; returns 1 when the end has been latched, else 0 with the next edge further away.
 * window 0: every edge up to the end (a synchronous exposure: no clock reads, whose time
 * the shortest exposure cannot spare). */
static void arm_next(void);

static uint8_t run_edges(uint32_t window)
{
    for (;;) {
        uint32_t at = next_edge();
        if (window) {
            uint32_t ovf;
            uint16_t tcnt;
            clock_read_wide_unlocked(&ovf, &tcnt);
            if ((int32_t)(at - ((ovf << 16) | tcnt)) > (int32_t)window)
                return 0;
        }
        if (next_step >= schedule.steps) {
            end_edges();
            return 1;
        }
        wait_until((uint16_t)at);
        PIN_HIGH(PIN_LATCH);
        PIN_LOW(PIN_LATCH);
        next_step++;
        shift_next();
    }
}

void exposure_start(const uint8_t *levels, uint32_t word, uint32_t exposure_us)
{
    uint32_t exposure_ticks = exposure_us * TICKS_PER_US;
    if (levels) {
        schedule_build(&schedule, levels, exposure_ticks);
    } else {
        schedule.rise_word = word;
        schedule.steps = 0;
    }
    next_step = 0;
    /* Load the first word now; it reaches the LEDs at the latch edge below. */
    chain_shift(schedule.rise_word);

    uint8_t sreg = SREG;
    cli();
    /* All bookkeeping happens before the rising edge, for a start LEAD_TICKS ahead, so
     * that only the next shift separates the rising edge from the first step or end. */
    uint32_t ovf;
    uint16_t tcnt;
    clock_read_wide_unlocked(&ovf, &tcnt);
    uint16_t start16 = (uint16_t)(tcnt + LEAD_TICKS);
    if (start16 < tcnt)
        ovf++;
    trigger_us = clock_ticks_to_us(ovf, start16);
    end_us = trigger_us + exposure_us;
    start_ticks = (ovf << 16) | start16;
    end_ticks = start_ticks + exposure_ticks;
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

    /* The word of the next edge: the first step's, or all off. */
    shift_next();

    state = RUNNING;
    if (run_edges(exposure_ticks <= SYNC_MAX_TICKS ? 0 : 2 * EARLY_TICKS))
        state = FINISHED;
    else
        arm_next();
    SREG = sreg;
}

/* Compare A EARLY_TICKS before the next edge (interrupts disabled; the edge is more than
 * 2 * EARLY_TICKS ahead).  A stale OCF1A flag is not cleared: it costs one early interrupt
 * that finds nothing due, while writing TIFR1 lost a pending overflow flag under simavr
 * (the 32-bit clock then ran a 65536-tick round behind). */
static void arm_next(void)
{
    OCR1A = (uint16_t)((uint16_t)next_edge() - EARLY_TICKS);
    TIMSK1 |= _BV(OCIE1A);
}

ISR(TIMER1_COMPA_vect)
{
    /* the edges due soon (a match a 65536-tick round early finds none) */
    uint8_t ended = run_edges(2 * EARLY_TICKS);
    if (ended) {
        TIMSK1 &= (uint8_t)~_BV(OCIE1A);
        state = FINISHED;
    } else if (next_step) {
        arm_next();
    }
}

uint8_t exposure_poll(void)
{
    uint8_t sreg = SREG;
    cli();
    /* checked with interrupts off: the compare interrupt may end the exposure between a
     * check before cli() and the edges below, which would then latch the end a second time */
    if (state != RUNNING) {
        SREG = sreg;
        return 0;
    }
    uint32_t ovf;
    uint16_t tcnt;
    clock_read_wide_unlocked(&ovf, &tcnt);
    int32_t left = (int32_t)(next_edge() - ((ovf << 16) | tcnt));
    /* The main loop stays awake within 2 ms of an edge and latches it itself if the
     * compare interrupt has not come (a safety net: a missed match would cost a whole
     * 32.8 ms timer round). */
    if (left <= (int32_t)(2 * EARLY_TICKS)) {
        if (run_edges(2 * EARLY_TICKS)) {
            TIMSK1 &= (uint8_t)~_BV(OCIE1A);
            state = FINISHED;
        } else {
            arm_next();
        }
    }
    SREG = sreg;
    return left < (int32_t)(2000U * TICKS_PER_US);
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
