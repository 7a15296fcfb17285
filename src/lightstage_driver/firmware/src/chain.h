/* The daisy chain of four 74HC595 shift registers that switches the 32 LEDs. */
#ifndef LIGHTSTAGE_CHAIN_H
#define LIGHTSTAGE_CHAIN_H

#include <stdint.h>

void chain_init(void);
/* Shift `word` into the chain, MSB first, without latching: after 32 clocks bit i sits
 * on chain output i (output 0 = QA of the register next to the Uno, output 31 = QH of the
 * last one).  The LEDs do not change until chain_latch(). */
void chain_shift(uint32_t word);
/* Shift 32 zeros (data held low, 32 unrolled clock pulses: ~8 us at 16 MHz, short enough
 * to run between a trigger's rising edge and the shortest exposure's end). */
void chain_shift_zeros(void);
/* Copy the shift registers to the outputs (RCLK pulse). */
void chain_latch(void);
/* Shift and latch: the LEDs show `word`. */
void chain_show(uint32_t word);

#endif
