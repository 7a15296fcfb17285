/* The light stage's command set (protocol v1): armed/lit patterns, FIRE, sequences,
 * the host watchdog and the duplicate-reply cache. */
#ifndef LIGHTSTAGE_STAGE_H
#define LIGHTSTAGE_STAGE_H

#include <stdint.h>

void stage_init(void);
/* Send EVT_READY. */
void stage_announce(void);
/* Do whatever is due; returns 1 when it should be called again without sleeping. */
uint8_t stage_poll(void);

#endif
