/* One exposure: LEDs on the chain and the camera trigger high for exactly exposure_us.
 *
 * Both trigger edges are placed on Timer1 tick boundaries (0.5 us at 16 MHz) by the same
 * kind of polling loop, so the trigger's width equals the exposure to within a few CPU
 * cycles.  The LED latch switches in the same instruction as the trigger when both pins
 * are on one port (the authors' D11/D8), else one instruction later.
 *
 * Graded levels (8 bits) are on-times: every LED with a level above 0 lights at the rising
 * edge and goes dark at level / 255 of the exposure, by re-latching the chain at the
 * sorted off-instants (schedule.h); a full-scale LED goes dark with the trigger. */
#ifndef LIGHTSTAGE_EXPOSURE_H
#define LIGHTSTAGE_EXPOSURE_H

#include <stdint.h>

void exposure_init(void);
/* Light the LEDs and raise the trigger now; lower the trigger and switch every LED off
 * exposure_us later.  `levels` (32 x 0..255, LED order) gives each LED's on-time; NULL
 * lights `word` for the whole exposure.  Short exposures finish before this returns. */
void exposure_start(const uint8_t *levels, uint32_t word, uint32_t exposure_us);
uint8_t exposure_running(void);
/* Main-loop side of a running exposure: latches an edge that is due if its compare
 * interrupt has not; returns 1 while an edge is less than 2 ms away (the main loop then
 * stays awake). */
uint8_t exposure_poll(void);
/* Nonzero when an exposure has ended and exposure_take_finished() has not been called. */
uint8_t exposure_finished(void);
/* 1 once after an exposure ended, with its trigger and end times (t_us). */
uint8_t exposure_take_finished(uint32_t *t_trigger_us, uint32_t *t_end_us);
/* Trigger low and every LED off at once (shift and latch zeros); a running exposure is
 * cancelled (no finish). */
void exposure_abort_all_off(void);

#endif
