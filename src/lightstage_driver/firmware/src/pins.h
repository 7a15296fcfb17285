/* The four wires of the rig: 74HC595 chain data (SER), shift clock (SRCLK), latch
 * (RCLK) and the camera trigger.  Arduino pin numbers come from uno_pins.h (-DPIN_...). */
#ifndef LIGHTSTAGE_PINS_H
#define LIGHTSTAGE_PINS_H

#include <avr/io.h>

#include "uno_pins.h"

#define UNO_PORT_REG(n) (*((n) < 8 ? &PORTD : (n) < 14 ? &PORTB : &PORTC))
#define UNO_DDR_REG(n) (*((n) < 8 ? &DDRD : (n) < 14 ? &DDRB : &DDRC))

#define PIN_HIGH(n) (UNO_PORT_REG(n) |= _BV(UNO_BIT(n)))
#define PIN_LOW(n) (UNO_PORT_REG(n) &= (uint8_t)~_BV(UNO_BIT(n)))
#define PIN_OUTPUT(n) (UNO_DDR_REG(n) |= _BV(UNO_BIT(n)))

/* Latch and trigger on the same port (the authors' D11 / D8 are both port B) switch in
 * the same instruction. */
#define LATCH_TRIGGER_SAME_PORT (UNO_PORT_LETTER(PIN_LATCH) == UNO_PORT_LETTER(PIN_TRIGGER))

#endif
