#include "chain.h"

#include "pins.h"

void chain_init(void)
{
    PIN_LOW(PIN_DATA);
    PIN_LOW(PIN_CLOCK);
    PIN_LOW(PIN_LATCH);
    PIN_OUTPUT(PIN_DATA);
    PIN_OUTPUT(PIN_CLOCK);
    PIN_OUTPUT(PIN_LATCH);
}

/* One bit: data low, then high if the bit is set (sbrc + sbi), then a clock pulse; ~9
 * cycles.  The data line may dip low between two set bits: the 74HC595 samples it only
 * at the clock's rising edge. */
#define SHIFT_BIT(b, n) \
    do { \
        PIN_LOW(PIN_DATA); \
        if ((b) & (1U << (n))) \
            PIN_HIGH(PIN_DATA); \
        PIN_HIGH(PIN_CLOCK); \
        PIN_LOW(PIN_CLOCK); \
    } while (0)

static inline __attribute__((always_inline)) void shift_byte(uint8_t b)
{
    SHIFT_BIT(b, 7);
    SHIFT_BIT(b, 6);
    SHIFT_BIT(b, 5);
    SHIFT_BIT(b, 4);
    SHIFT_BIT(b, 3);
    SHIFT_BIT(b, 2);
    SHIFT_BIT(b, 1);
    SHIFT_BIT(b, 0);
}

void chain_shift(uint32_t word)
{
    /* MSB first, unrolled: a graded exposure re-latches the chain at instants at least
     * one shift-out apart (schedule.h), so its speed sets how finely they can be placed. */
    shift_byte((uint8_t)(word >> 24));
    shift_byte((uint8_t)(word >> 16));
    shift_byte((uint8_t)(word >> 8));
    shift_byte((uint8_t)word);
    PIN_LOW(PIN_DATA);
}

#define CLOCK_PULSE() \
    do { \
        PIN_HIGH(PIN_CLOCK); \
        PIN_LOW(PIN_CLOCK); \
    } while (0)
#define CLOCK_PULSE_4() \
    do { \
        CLOCK_PULSE(); \
        CLOCK_PULSE(); \
        CLOCK_PULSE(); \
        CLOCK_PULSE(); \
    } while (0)

void chain_shift_zeros(void)
{
    PIN_LOW(PIN_DATA);
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
    CLOCK_PULSE_4();
}

void chain_latch(void)
{
    PIN_HIGH(PIN_LATCH);
    PIN_LOW(PIN_LATCH);
}

void chain_show(uint32_t word)
{
    chain_shift(word);
    chain_latch();
}
