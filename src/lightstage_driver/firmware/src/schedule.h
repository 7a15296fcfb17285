/* The latch schedule of one graded exposure: when to re-latch the 74HC595 chain so that
 * each LED is lit for level / 255 of the exposure (docs/PROTOCOL.md, "Graded levels").
 *
 * All times are Timer1 ticks (0.5 us) from the rising edge.  LED i's ideal off-instant is
 * round(level_i * E / 255).  After a latch the next word needs SHIFT_TICKS to be shifted
 * in, and the zeros of the end need ZERO_TICKS; so latches are at least SHIFT_TICKS apart
 * and the last one at least ZERO_TICKS before the end.  Off-instants that cannot get a
 * latch of their own share one: those within half a shift-out of the previous latch go
 * off with it (early), the others at the next possible one (late); near the end they go
 * to the nearer of the previous latch and the end.  Every LED's off-instant is therefore
 * within max(SHIFT_TICKS / 2 + 1, (SHIFT_TICKS + ZERO_TICKS) / 2 + 1, ZERO_TICKS) ticks,
 * i.e. under one shift-out, of its ideal one.  lightstage_driver/firmware_model.py computes
 * the same schedule (the differential test compares the latched words). */
#ifndef LIGHTSTAGE_SCHEDULE_H
#define LIGHTSTAGE_SCHEDULE_H

#include <stdint.h>

#include "config.h"

/* Latch-to-latch time of a 32-bit word's shift-out (18 us of clocking, ~30 us with the
 * loop's bookkeeping, measured in simavr) and of the end's unrolled zeros (8 us, ~19 us
 * with bookkeeping), rounded up with margin. */
#define SHIFT_TICKS 72U
#define ZERO_TICKS 40U
#define LEVEL_FULL 255U

typedef struct {
    uint32_t rise_word;              /* latched at the rising edge */
    uint8_t steps;                   /* re-latches between the edges */
    uint32_t at[LED_COUNT];          /* tick of step k from the rising edge, increasing */
    uint32_t word[LED_COUNT];        /* the word latched at step k */
} schedule_t;

/* Off-instant of `level` in an exposure of `ticks`: round(level * ticks / 255). */
uint32_t schedule_off_tick(uint8_t level, uint32_t ticks);
void schedule_build(schedule_t *s, const uint8_t *levels, uint32_t ticks);

#endif
