/* Light stage firmware for an ATmega328P (Arduino Uno): speaks protocol v1 on UART0,
 * drives 32 LEDs through a chain of four 74HC595 and fires the camera trigger. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "chain.h"
#include "clock.h"
#include "exposure.h"
#include "stage.h"
#include "uart.h"

/* A hardware-watchdog reset leaves the watchdog running: stop it before main() so that
 * the start-up code cannot be reset again. */
void early_wdt_off(void) __attribute__((naked, used, section(".init3")));
void early_wdt_off(void)
{
    MCUSR = 0;
    wdt_disable();
}

int main(void)
{
    chain_init();
    chain_show(0); /* the 74HC595 outputs are undefined at power-up */
    exposure_init();
    clock_init();
    uart_init();
    stage_init();
    /* Against our own hangs (not the host watchdog of the protocol): the main loop runs
     * at least every millisecond. */
    wdt_enable(WDTO_250MS);
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    stage_announce();

    for (;;) {
        wdt_reset();
        if (stage_poll())
            continue;
        /* Sleep until the next interrupt (a received byte or the 1 kHz tick); sei
         * followed by sleep is atomic on AVR, so no wake-up is lost. */
        cli();
        if (uart_rx_pending() || exposure_finished() || exposure_poll()) {
            sei();
            continue;
        }
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
}
