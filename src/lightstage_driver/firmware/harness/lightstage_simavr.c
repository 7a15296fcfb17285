/* Hardware-in-the-loop rig in simulation: runs the light stage firmware in simavr,
 * bridges its UART0 to a pseudo-terminal the driver opens like a USB serial port, and
 * watches the 74HC595 chain and trigger pins.
 *
 *   lightstage_simavr FIRMWARE.elf [--no-throttle] [--hold] [--trace-bytes]
 *
 * Reports, one line each on stdout (everything simavr prints goes to stderr):
 *   F <hz>                   simulated clock frequency
 *   PTY <path>               the serial port to open (a pty slave)
 *   L <cycle> <word>         a latch (RCLK) rising edge: the 32-bit word now on the chain's
 *                            outputs, hex, bit i = output i (QA of the first register = 0)
 *   T <rise> <fall>          a trigger pulse: rising and falling edge cycles
 *   R <cycle>                the MCU was reset (stdin "reset")
 *   X <cycle> <state>        the simulated CPU stopped (crashed or done)
 *   S <cycle>                answer to stdin "sync": all earlier events are out
 * Cycles count from power-up at the simulated clock (exact widths: fall - rise).
 *
 * Commands on stdin, one per line: "reset" (pulse the reset line, as DTR does on an Uno),
 * "sync" (answered by an S line), "status" (harness state to stderr),
 * "run" (start the CPU when started with --hold), "quit".  End of input also quits, so
 * the harness never outlives the process that started it.
 *
 * The pty bridge is done here, single-threaded, instead of with simavr's uart_pty part,
 * which creates a shared /tmp/simavr-uart0 link, prints banners on stdout and can hang in
 * its stop function.  Simulated time is throttled to wall time (it waits whenever it is
 * ahead, and forgets lag beyond 50 ms instead of catching up in a burst), so the
 * firmware's millisecond timeouts mean the same as the host's; --no-throttle runs as fast
 * as the host can.  --trace-bytes logs every UART byte with its cycle to stderr.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_elf.h"
#include "sim_irq.h"

#include "uno_pins.h"

#ifndef HARNESS_F_CPU
#define HARNESS_F_CPU 16000000UL
#endif
#ifndef HARNESS_MCU
#define HARNESS_MCU "atmega328p"
#endif

#define SLICE_CYCLES 1600            /* run this much simulated time between I/O polls */
#define MAX_LAG_NS (50 * 1000000LL)  /* forget lag beyond this (no catch-up bursts) */
#define UCSR0B_ADDR 0xC1             /* ATmega328P data-space address */
#define RXEN0_BIT 4

static avr_t *avr;
static FILE *events;
static int master_fd = -1;

/* 74HC595 chain model */
static uint32_t shift_reg;
static int data_level, clock_level, latch_level, trigger_level;
static avr_cycle_count_t trigger_rise;

/* host -> firmware bytes waiting for room in the simulated UART */
static uint8_t rx_queue[65536];
static size_t rx_head, rx_tail;
static int uart_xoff;

/* firmware -> host bytes waiting for the pty; written when the simulated line has been
 * idle for TX_IDLE_CYCLES, so that a frame reaches the host in one write even if this
 * process is descheduled between two of its bytes (a host decoder may drop a frame that
 * stalls for 10 ms between reads).  A byte takes 1496 cycles; the firmware may hold its
 * transmit interrupt off for up to ~2000 cycles while it starts a short exposure. */
#define TX_IDLE_CYCLES 5000
static uint8_t tx_queue[65536];
static size_t tx_len;
static avr_cycle_count_t tx_last_cycle;
static int tx_stalled; /* the pty is full: the host is not reading */

static void on_data(avr_irq_t *irq, uint32_t value, void *param)
{
    data_level = value & 1;
}

static void on_clock(avr_irq_t *irq, uint32_t value, void *param)
{
    int level = value & 1;
    /* SRCLK rising edge: every register shifts, SER enters at output 0 */
    if (level && !clock_level)
        shift_reg = (shift_reg << 1) | (uint32_t)data_level;
    clock_level = level;
}

static void on_latch(avr_irq_t *irq, uint32_t value, void *param)
{
    int level = value & 1;
    if (level && !latch_level)
        fprintf(events, "L %llu %08x\n", (unsigned long long)avr->cycle, shift_reg);
    latch_level = level;
}

static void on_trigger(avr_irq_t *irq, uint32_t value, void *param)
{
    int level = value & 1;
    if (level && !trigger_level)
        trigger_rise = avr->cycle;
    else if (!level && trigger_level)
        fprintf(events, "T %llu %llu\n", (unsigned long long)trigger_rise,
                (unsigned long long)avr->cycle);
    trigger_level = level;
}

static int trace_bytes;

static void on_uart_output(avr_irq_t *irq, uint32_t value, void *param)
{
    if (trace_bytes)
        fprintf(stderr, "O %llu %02x\n", (unsigned long long)avr->cycle, value & 0xFF);
    if (tx_len < sizeof(tx_queue))
        tx_queue[tx_len++] = (uint8_t)value;
    tx_last_cycle = avr->cycle;
}

static void on_uart_xon(avr_irq_t *irq, uint32_t value, void *param)
{
    uart_xoff = 0;
}

static void on_uart_xoff(avr_irq_t *irq, uint32_t value, void *param)
{
    uart_xoff = value & 1;
}

static void watch_pin(int uno_pin, avr_irq_notify_t notify)
{
    avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(UNO_PORT_LETTER(uno_pin)),
                                   UNO_BIT(uno_pin));
    avr_irq_register_notify(irq, notify, NULL);
}

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

/* simavr's own sleep callback would usleep(); throttling is done in the main loop. */
static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
}

/* A sleeping CPU is skipped to its next timer event (up to a millisecond away at the
 * firmware's 1 kHz tick), which would put simulated time that far ahead of wall time; host
 * input arriving then would be answered only when wall time catches up.  This timer keeps
 * such skips short. */
#define PACE_CYCLES 4800 /* 0.3 ms: ~0.15 ms added latency on average; ~9 % of a core idle */

static avr_cycle_count_t pace(avr_t *a, avr_cycle_count_t when, void *param)
{
    return when + PACE_CYCLES;
}

static void reset_observers(void)
{
    /* a reset makes every port an input again: the lines read low (pull-downs on the
     * 74HC595 inputs and the trigger, as on the rig) */
    data_level = clock_level = latch_level = trigger_level = 0;
    uart_xoff = 0;
}

static void flush_tx(void)
{
    size_t done = 0;
    while (done < tx_len) {
        ssize_t n = write(master_fd, tx_queue + done, tx_len - done);
        if (n <= 0)
            break; /* host not reading: keep the rest for later */
        done += (size_t)n;
    }
    memmove(tx_queue, tx_queue + done, tx_len - done);
    tx_len -= done;
    tx_stalled = tx_len > 0;
}

static void feed_uart(void)
{
    avr_irq_t *in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    /* bytes wait until the firmware has enabled its receiver (a real board would drop
     * them; the driver's connect loop would resend) */
    if (!(avr->data[UCSR0B_ADDR] & (1 << RXEN0_BIT)))
        return;
    while (!uart_xoff && rx_tail != rx_head) {
        if (trace_bytes)
            fprintf(stderr, "I %llu %02x\n", (unsigned long long)avr->cycle, rx_queue[rx_tail]);
        avr_raise_irq(in, rx_queue[rx_tail]);
        rx_tail = (rx_tail + 1) % sizeof(rx_queue);
    }
}

static void read_master(void)
{
    uint8_t buf[4096];
    for (;;) {
        size_t room = (rx_tail + sizeof(rx_queue) - rx_head - 1) % sizeof(rx_queue);
        if (room == 0)
            return;
        ssize_t n = read(master_fd, buf, room < sizeof(buf) ? room : sizeof(buf));
        if (n <= 0)
            return;
        for (ssize_t i = 0; i < n; i++) {
            rx_queue[rx_head] = buf[i];
            rx_head = (rx_head + 1) % sizeof(rx_queue);
        }
    }
}

/* Returns 0 to quit. */
static int read_commands(int *hold)
{
    static char line[256];
    static size_t len;
    char buf[256];
    ssize_t n = read(STDIN_FILENO, buf, sizeof(buf));
    if (n == 0)
        return 0;
    if (n < 0)
        return errno == EAGAIN || errno == EINTR;
    for (ssize_t i = 0; i < n; i++) {
        if (buf[i] != '\n') {
            if (len < sizeof(line) - 1)
                line[len++] = buf[i];
            continue;
        }
        line[len] = 0;
        len = 0;
        if (!strcmp(line, "quit"))
            return 0;
        if (!strcmp(line, "run"))
            *hold = 0;
        else if (!strcmp(line, "sync"))
            /* a barrier: every event up to now has been written before this line */
            fprintf(events, "S %llu\n", (unsigned long long)avr->cycle);
        else if (!strcmp(line, "status")) {
            fprintf(stderr,
                    "lightstage_simavr: cycle %llu state %d pc 0x%x sreg 0x%02x ucsr0a 0x%02x "
                    "ucsr0b 0x%02x xoff %d rx_queued %zu tx_queued %zu\n",
                    (unsigned long long)avr->cycle, avr->state, avr->pc, avr->data[0x5F],
                    avr->data[0xC0], avr->data[UCSR0B_ADDR], uart_xoff,
                    (rx_head + sizeof(rx_queue) - rx_tail) % sizeof(rx_queue), tx_len);
            fflush(stderr);
        } else if (!strcmp(line, "reset")) {
            avr_reset(avr);
            avr_cycle_timer_cancel(avr, pace, NULL);
            avr_cycle_timer_register(avr, PACE_CYCLES, pace, NULL);
            reset_observers();
            fprintf(events, "R %llu\n", (unsigned long long)avr->cycle);
        } else
            fprintf(stderr, "lightstage_simavr: unknown command '%s' (reset, run, quit)\n",
                    line);
    }
    return 1;
}

static int open_pty(char *slave_name, size_t size)
{
    int slave_fd;
    struct termios tio;
    if (openpty(&master_fd, &slave_fd, NULL, NULL, NULL) < 0) {
        perror("lightstage_simavr: openpty");
        return -1;
    }
    /* raw bytes both ways, like a USB serial port */
    tcgetattr(slave_fd, &tio);
    cfmakeraw(&tio);
    cfsetspeed(&tio, B115200);
    tcsetattr(slave_fd, TCSANOW, &tio);
    snprintf(slave_name, size, "%s", ttyname(slave_fd));
    /* keep the slave open so the master never sees a hang-up between host sessions */
    fcntl(master_fd, F_SETFL, fcntl(master_fd, F_GETFL) | O_NONBLOCK);
    return 0;
}

int main(int argc, char **argv)
{
    const char *elf = NULL;
    int throttle = 1, hold = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--no-throttle"))
            throttle = 0;
        else if (!strcmp(argv[i], "--trace-bytes"))
            trace_bytes = 1;
        else if (!strcmp(argv[i], "--hold"))
            hold = 1;
        else if (argv[i][0] != '-' && !elf)
            elf = argv[i];
        else {
            fprintf(stderr, "usage: %s FIRMWARE.elf [--no-throttle] [--hold] [--trace-bytes]\n",
                    argv[0]);
            return 2;
        }
    }
    if (!elf) {
        fprintf(stderr, "usage: %s FIRMWARE.elf [--no-throttle] [--hold]\n", argv[0]);
        return 2;
    }

    /* Events go to the real stdout; anything simavr prints goes to stderr. */
    int events_fd = dup(STDOUT_FILENO);
    dup2(STDERR_FILENO, STDOUT_FILENO);
    events = fdopen(events_fd, "w");
    signal(SIGPIPE, SIG_IGN);

    elf_firmware_t fw;
    memset(&fw, 0, sizeof(fw));
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "lightstage_simavr: cannot read firmware '%s' (build it with make)\n",
                elf);
        return 1;
    }
    snprintf(fw.mmcu, sizeof(fw.mmcu), "%s", HARNESS_MCU);
    fw.frequency = HARNESS_F_CPU;
    avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr) {
        fprintf(stderr, "lightstage_simavr: simavr does not know MCU '%s'\n", fw.mmcu);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->sleep = no_sleep;
    avr_cycle_timer_register(avr, PACE_CYCLES, pace, NULL);
    avr->log = 1; /* errors only */

    uint32_t flags = 0; /* no stdio echo of UART output, no poll sleeping */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart_output, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            on_uart_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            on_uart_xoff, NULL);
    watch_pin(PIN_DATA, on_data);
    watch_pin(PIN_CLOCK, on_clock);
    watch_pin(PIN_LATCH, on_latch);
    watch_pin(PIN_TRIGGER, on_trigger);

    char slave_name[256];
    if (open_pty(slave_name, sizeof(slave_name)) < 0)
        return 1;
    fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);

    fprintf(events, "F %lu\nPTY %s\n", (unsigned long)HARNESS_F_CPU, slave_name);
    fflush(events);

    int64_t wall0 = now_ns();
    avr_cycle_count_t cycle0 = avr->cycle;
    for (;;) {
        if (!hold) {
            avr_cycle_count_t until = avr->cycle + SLICE_CYCLES;
            while (avr->cycle < until) {
                int state = avr_run(avr);
                if (state == cpu_Done || state == cpu_Crashed) {
                    fprintf(events, "X %llu %s\n", (unsigned long long)avr->cycle,
                            state == cpu_Done ? "done" : "crashed");
                    fflush(events);
                    return 3;
                }
            }
        }
        fflush(events); /* pin events first: a reply never overtakes the events before it */
        if (tx_len && (avr->cycle - tx_last_cycle > TX_IDLE_CYCLES || tx_len > 4096 || hold))
            flush_tx();

        int timeout_ms = 0;
        int64_t wall = now_ns() - wall0;
        int64_t sim = (int64_t)((avr->cycle - cycle0) * 1000000000.0 / HARNESS_F_CPU);
        if (hold) {
            timeout_ms = 10;
            wall0 = now_ns() - sim; /* the clock stands still while held */
        } else if (throttle) {
            if (sim > wall)
                timeout_ms = (int)((sim - wall + 999999) / 1000000);
            else if (wall - sim > MAX_LAG_NS)
                wall0 += wall - sim - MAX_LAG_NS;
        }
        struct pollfd fds[2] = {{master_fd, POLLIN, 0}, {STDIN_FILENO, POLLIN, 0}};
        if (tx_stalled)
            fds[0].events |= POLLOUT;
        if (timeout_ms > 0 || hold) {
            struct timespec ts = {0, 0};
            if (throttle && !hold) {
                int64_t ahead = sim - (now_ns() - wall0);
                if (ahead < 0)
                    ahead = 0;
                ts.tv_sec = ahead / 1000000000LL;
                ts.tv_nsec = ahead % 1000000000LL;
            } else {
                ts.tv_nsec = 10 * 1000000L;
            }
            ppoll(fds, 2, &ts, NULL);
        } else {
            poll(fds, 2, 0);
        }
        if (fds[0].revents & POLLIN)
            read_master();
        if (fds[1].revents & (POLLIN | POLLHUP)) {
            if (!read_commands(&hold))
                break;
        }
        feed_uart();
    }
    fflush(events);
    return 0;
}
