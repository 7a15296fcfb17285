/* Arduino Uno digital pin numbers -> ATmega328P port and bit.
 *
 * Shared by the firmware (AVR) and the simavr harness (host), so that both agree on
 * the wiring chosen at build time with -DPIN_DATA=.. -DPIN_CLOCK=.. -DPIN_LATCH=..
 * -DPIN_TRIGGER=.. (Arduino numbering: D0-D7 = PD0-PD7, D8-D13 = PB0-PB5,
 * A0-A5 = 14-19 = PC0-PC5).  D0/D1 are the UART and cannot be used.
 */
#ifndef LIGHTSTAGE_UNO_PINS_H
#define LIGHTSTAGE_UNO_PINS_H

/* Defaults: the authors' rig (data D12, clock D10, latch D11, trigger D8). */
#ifndef PIN_DATA
#define PIN_DATA 12
#endif
#ifndef PIN_CLOCK
#define PIN_CLOCK 10
#endif
#ifndef PIN_LATCH
#define PIN_LATCH 11
#endif
#ifndef PIN_TRIGGER
#define PIN_TRIGGER 8
#endif

/* 'B', 'C' or 'D' */
#define UNO_PORT_LETTER(n) ((n) < 8 ? 'D' : (n) < 14 ? 'B' : 'C')
#define UNO_BIT(n) ((n) < 8 ? (n) : (n) < 14 ? (n) - 8 : (n) - 14)

#define UNO_PIN_VALID(n) ((n) >= 2 && (n) <= 19)

#if !UNO_PIN_VALID(PIN_DATA) || !UNO_PIN_VALID(PIN_CLOCK) || !UNO_PIN_VALID(PIN_LATCH) || \
    !UNO_PIN_VALID(PIN_TRIGGER)
#error "PIN_DATA/PIN_CLOCK/PIN_LATCH/PIN_TRIGGER must be Uno pins 2..19 (D0/D1 are the UART)"
#endif

#if PIN_DATA == PIN_CLOCK || PIN_DATA == PIN_LATCH || PIN_DATA == PIN_TRIGGER || \
    PIN_CLOCK == PIN_LATCH || PIN_CLOCK == PIN_TRIGGER || PIN_LATCH == PIN_TRIGGER
#error "PIN_DATA, PIN_CLOCK, PIN_LATCH and PIN_TRIGGER must be four different pins"
#endif

#endif
