/* Build-time constants of the light stage firmware (protocol v1, docs/PROTOCOL.md). */
#ifndef LIGHTSTAGE_CONFIG_H
#define LIGHTSTAGE_CONFIG_H

#include <stdint.h>

#ifndef F_CPU
#define F_CPU 16000000UL
#endif

#define FW_MAJOR 1
#define FW_MINOR 1
#define FW_PATCH 0
#define FW_NAME "lightstage-avr"

#define PROTOCOL_VERSION 1
#define LED_COUNT 32
#define SITES 8
#define CHANNELS 4
#define PWM_BITS 8 /* graded levels as on-times within the exposure (schedule.h) */

#define MIN_EXPOSURE_US 20UL
#define MAX_EXPOSURE_US 2000000UL
#define MAX_SEQUENCE 16
#define MAX_PAYLOAD 136
#define MAX_GAP_US 1000000UL

#define WATCHDOG_DEFAULT_MS 1000
#define WATCHDOG_MIN_MS 50
#define WATCHDOG_MAX_MS 60000

/* Inter-byte timeout of the frame receiver. */
#define INTERBYTE_TIMEOUT_MS 10

#define BAUD 115200UL

/* Timer1 runs at F_CPU / 8: one tick is 0.5 us at 16 MHz.  Only 16 MHz is supported:
 * at 8 MHz, 115200 baud is 3.5 % off, too far for a reliable link. */
#if F_CPU == 16000000UL
#define TICKS_PER_US 2
#else
#error "F_CPU must be 16000000UL (Arduino Uno)"
#endif
#define TIMER1_PRESCALER_BITS (1 << CS11)

#endif
