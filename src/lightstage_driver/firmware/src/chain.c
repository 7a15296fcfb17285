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

void chain_shift(uint32_t word)
{
    /* Data is set in its own instruction before the clock's rising edge (SER setup
     * time); sbi/cbi on the fixed pins keep it at ~10 cycles a bit. */
    for (uint8_t i = 0; i < 32; i++) {
        if (word & 0x80000000UL)
            PIN_HIGH(PIN_DATA);
        else
            PIN_LOW(PIN_DATA);
        PIN_HIGH(PIN_CLOCK);
        word <<= 1;
        PIN_LOW(PIN_CLOCK);
    }
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
