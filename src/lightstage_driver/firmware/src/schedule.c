#include "schedule.h"

/* x / 255 for x < 65535, without a division */
static inline uint16_t div255(uint16_t x)
{
    return (uint16_t)(x + 1 + (x >> 8)) >> 8;
}

/* round(level * ticks / 255) without a 40-bit product, ticks = q * 255 + r */
static inline uint32_t off_tick(uint8_t level, uint32_t q, uint16_t r)
{
    return level * q + div255((uint16_t)(level * r + LEVEL_FULL / 2));
}

uint32_t schedule_off_tick(uint8_t level, uint32_t ticks)
{
    uint32_t q = ticks / LEVEL_FULL;
    return off_tick(level, q, (uint16_t)(ticks - q * LEVEL_FULL));
}

/* Drop `mask` from the word latched last (the rising edge's when there is no step yet). */
static void off_at_last(schedule_t *s, uint32_t mask)
{
    if (s->steps)
        s->word[s->steps - 1] &= ~mask;
    else
        s->rise_word &= ~mask;
}

void schedule_build(schedule_t *s, const uint8_t *levels, uint32_t ticks)
{
    /* the LEDs with a level strictly between 0 and full, sorted by level */
    uint8_t order[LED_COUNT];
    uint8_t n = 0;
    uint32_t word = 0;
    for (uint8_t i = 0; i < LED_COUNT; i++) {
        uint8_t level = levels[i];
        if (!level)
            continue;
        word |= 1UL << i;
        if (level == LEVEL_FULL)
            continue;
        uint8_t k = n++;
        while (k && levels[order[k - 1]] > level) {
            order[k] = order[k - 1];
            k--;
        }
        order[k] = i;
    }
    s->rise_word = word;
    s->steps = 0;
    uint32_t q = ticks / LEVEL_FULL; /* the one 32-bit division */
    uint16_t r = (uint16_t)(ticks - q * LEVEL_FULL);
    uint32_t last = 0; /* tick of the last latch (0: the rising edge) */
    uint8_t i = 0;
    uint32_t t_i = n ? off_tick(levels[order[0]], q, r) : 0; /* off-instant of order[i] */
    while (i < n) {
        /* one group: every LED whose off-instant is this tick */
        uint32_t t = t_i;
        uint32_t mask = 0;
        while (i < n && t_i == t) {
            mask |= 1UL << order[i++];
            if (i < n)
                t_i = off_tick(levels[order[i]], q, r);
        }
        if (t >= ticks)
            break; /* these go dark with the trigger */
        uint32_t next = last + SHIFT_TICKS; /* the earliest next latch */
        if (t <= last || (t < next && 2 * (t - last) <= SHIFT_TICKS) ||
            (next + ZERO_TICKS > ticks && t - last <= ticks - t)) {
            off_at_last(s, mask); /* with the last latch (a merged step, or early) */
        } else if (next + ZERO_TICKS > ticks || t + ZERO_TICKS > ticks) {
            break; /* no latch fits before the end: these and the rest go dark at the end */
        } else {
            uint32_t at = t < next ? next : t; /* a latch of its own, or the next possible */
            word &= ~mask;
            s->at[s->steps] = at;
            s->word[s->steps] = word;
            s->steps++;
            last = at;
            continue;
        }
        word &= ~mask;
    }
}
