#include "stage.h"

#include <string.h>

#include "chain.h"
#include "clock.h"
#include "config.h"
#include "exposure.h"
#include "link.h"
#include "schedule.h"

enum {
    CMD_IDENTIFY = 0x01,
    CMD_HEARTBEAT = 0x02,
    CMD_SET_PATTERN = 0x03,
    CMD_SET_LEVELS = 0x04,
    CMD_FIRE = 0x05,
    CMD_RUN_SEQUENCE = 0x06,
    CMD_ALL_OFF = 0x07,
    CMD_SET_WATCHDOG = 0x08,
    CMD_SET_LEVEL_TABLE = 0x09,
    CMD_RUN_LEVEL_SEQUENCE = 0x0A,
    REPLY = 0x80,
    EVT_READY = 0x40,
    EVT_TRIGGER = 0x41,
    EVT_SEQUENCE_DONE = 0x42,
    EVT_WATCHDOG = 0x43,
    NAK = 0xFF,
};

enum {
    NAK_BAD_CRC = 1,
    NAK_BAD_LENGTH = 2,
    NAK_UNKNOWN_COMMAND = 3,
    NAK_EXPOSURE_RANGE = 4,
    NAK_SEQUENCE_LENGTH = 5,
    NAK_BUSY = 6,
    NAK_UNSUPPORTED = 7,
    NAK_LEVEL_RANGE = 8,
    NAK_WATCHDOG_RANGE = 9,
    NAK_BAD_FLAGS = 10,
    NAK_GAP_RANGE = 11,
    NAK_ROW_RANGE = 12,
};

enum { SEQ_COMPLETE = 0, SEQ_ABORTED_ALL_OFF = 1, SEQ_ABORTED_WATCHDOG = 2 };

#define FLAG_SHOW_NOW 0x01
#define CACHE_PAYLOAD 28
#define IDENTITY_FIXED 20

static frame_t frame;

static uint32_t armed; /* LEDs with a level above 0 in the next FIRE */
static uint8_t armed_levels[LED_COUNT]; /* the next FIRE's levels (0 or 255 after SET_PATTERN) */
static uint32_t lit;   /* what the LEDs show now */

/* graded patterns for RUN_LEVEL_SEQUENCE (SET_LEVEL_TABLE); zero after reset */
static uint8_t level_table[MAX_SEQUENCE][LED_COUNT];

/* host watchdog */
static uint16_t watchdog_ms = WATCHDOG_DEFAULT_MS;
static uint32_t activity_ms;  /* last valid frame or exposure end */
static uint8_t silence_handled; /* tripped during the current silence */
static uint8_t tripped_since_heartbeat;

/* duplicate-reply cache */
static uint8_t cache_valid, cache_seq, cache_cmd, cache_reply_cmd, cache_len;
static uint8_t cache_payload[CACHE_PAYLOAD];

/* FIRE waiting for its exposure's end */
static uint8_t fire_pending, fire_seq;

/* RUN_SEQUENCE */
static struct {
    uint8_t running, seq, count, started, done, waiting, graded;
    uint32_t gap_us, next_us;
    uint32_t word[MAX_SEQUENCE];  /* RUN_SEQUENCE */
    uint8_t row[MAX_SEQUENCE];    /* RUN_LEVEL_SEQUENCE: level_table rows */
    uint32_t exposure_us[MAX_SEQUENCE];
} sequence;

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)p[0] | ((uint16_t)p[1] << 8);
}

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

/* Send a reply to the command in `frame` and remember it for a duplicate. */
static void reply(uint8_t cmd, const uint8_t *payload, uint8_t len, uint8_t cacheable)
{
    link_send(frame.seq, cmd, payload, len);
    if (cacheable && len <= CACHE_PAYLOAD) {
        cache_valid = 1;
        cache_seq = frame.seq;
        cache_cmd = frame.cmd;
        cache_reply_cmd = cmd;
        cache_len = len;
        memcpy(cache_payload, payload, len);
    }
}

static void reply_u32(uint32_t v)
{
    uint8_t p[4];
    put_u32(p, v);
    reply(frame.cmd | REPLY, p, 4, 1);
}

static void nak(uint8_t reason, uint32_t value, uint8_t cacheable)
{
    uint8_t p[6];
    p[0] = frame.cmd;
    p[1] = reason;
    put_u32(p + 2, value);
    reply(NAK, p, 6, cacheable);
}

static uint8_t identity(uint8_t *p)
{
    p[0] = PROTOCOL_VERSION;
    p[1] = FW_MAJOR;
    p[2] = FW_MINOR;
    p[3] = FW_PATCH;
    p[4] = LED_COUNT;
    p[5] = SITES;
    p[6] = CHANNELS;
    p[7] = PWM_BITS;
    put_u32(p + 8, MIN_EXPOSURE_US);
    put_u32(p + 12, MAX_EXPOSURE_US);
    put_u16(p + 16, watchdog_ms);
    p[18] = MAX_SEQUENCE;
    p[19] = MAX_PAYLOAD;
    memcpy(p + IDENTITY_FIXED, FW_NAME, sizeof(FW_NAME) - 1);
    return IDENTITY_FIXED + sizeof(FW_NAME) - 1;
}

void stage_init(void)
{
    armed = lit = 0;
    activity_ms = clock_ms();
}

void stage_announce(void)
{
    uint8_t p[IDENTITY_FIXED + 16];
    link_send(0, EVT_READY, p, identity(p));
}

static uint8_t exposure_in_range(uint32_t us)
{
    return us >= MIN_EXPOSURE_US && us <= MAX_EXPOSURE_US;
}

static void set_armed_word(uint32_t word)
{
    armed = word;
    for (uint8_t i = 0; i < LED_COUNT; i++, word >>= 1)
        armed_levels[i] = word & 1 ? LEVEL_FULL : 0;
}

static void sequence_finish(uint8_t status)
{
    uint8_t p[2] = {sequence.done, status};
    sequence.running = 0;
    link_send(sequence.seq, EVT_SEQUENCE_DONE, p, 2);
}

static void service_exposure_end(void);

/* Every LED off, trigger low, armed pattern cleared, a sequence aborted with `status`. */
static void all_off(uint8_t status)
{
    /* an exposure that ended just now is reported before the abort */
    service_exposure_end();
    if (lit || exposure_running())
        exposure_abort_all_off();
    lit = 0;
    set_armed_word(0);
    if (sequence.running)
        sequence_finish(status);
}

static void do_identify(void)
{
    cache_valid = 0;
    if (frame.len != 0)
        return nak(NAK_BAD_LENGTH, frame.len, 0);
    uint8_t p[IDENTITY_FIXED + 16];
    reply(CMD_IDENTIFY | REPLY, p, identity(p), 0);
}

static void do_heartbeat(void)
{
    if (frame.len != 0)
        return nak(NAK_BAD_LENGTH, frame.len, 0);
    uint8_t p[7];
    put_u32(p, clock_us());
    p[4] = (lit ? 1 : 0) | (sequence.running ? 2 : 0) | (tripped_since_heartbeat ? 4 : 0);
    put_u16(p + 5, link_rx_errors());
    tripped_since_heartbeat = 0;
    reply(CMD_HEARTBEAT | REPLY, p, 7, 0);
}

static void do_set_pattern(void)
{
    if (frame.len != 5)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    uint8_t flags = frame.payload[0];
    if (flags & (uint8_t)~FLAG_SHOW_NOW)
        return nak(NAK_BAD_FLAGS, flags, 1);
    uint32_t word = get_u32(frame.payload + 1);
    if (flags & FLAG_SHOW_NOW) {
        chain_show(word);
        lit = word;
    }
    set_armed_word(word);
    reply_u32(clock_us());
}

static void do_set_levels(void)
{
    if (frame.len != 1 + 2 * LED_COUNT)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    for (uint8_t i = 0; i < LED_COUNT; i++) {
        uint16_t level = get_u16(frame.payload + 1 + 2 * i);
        if (level > LEVEL_FULL)
            return nak(NAK_LEVEL_RANGE, ((uint32_t)i << 16) | level, 1);
    }
    uint8_t flags = frame.payload[0];
    if (flags & (uint8_t)~FLAG_SHOW_NOW)
        return nak(NAK_BAD_FLAGS, flags, 1);
    armed = 0;
    for (uint8_t i = 0; i < LED_COUNT; i++) {
        armed_levels[i] = frame.payload[1 + 2 * i];
        if (armed_levels[i])
            armed |= 1UL << i;
    }
    /* without an exposure there is no fraction to take: SHOW_NOW lights every level > 0 */
    if (flags & FLAG_SHOW_NOW) {
        chain_show(armed);
        lit = armed;
    }
    reply_u32(clock_us());
}

static void do_set_level_table(void)
{
    if (frame.len < 1 + LED_COUNT || (frame.len - 1) % LED_COUNT)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    uint8_t first = frame.payload[0];
    uint8_t rows = (uint8_t)((frame.len - 1) / LED_COUNT);
    if (first + rows > MAX_SEQUENCE)
        return nak(NAK_ROW_RANGE, first + rows - 1, 1);
    memcpy(level_table[first], frame.payload + 1, rows * LED_COUNT);
    uint8_t p[2] = {first, rows};
    reply(CMD_SET_LEVEL_TABLE | REPLY, p, 2, 1);
}

static void do_fire(void)
{
    if (frame.len != 4)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    uint32_t exposure_us = get_u32(frame.payload);
    if (!exposure_in_range(exposure_us))
        return nak(NAK_EXPOSURE_RANGE, exposure_us, 1);
    fire_pending = 1;
    fire_seq = frame.seq;
    lit = armed;
    exposure_start(armed_levels, 0, exposure_us);
    /* the reply goes out when the exposure has ended (stage_poll) */
}

/* RUN_SEQUENCE entries are (word u32, exposure u32); RUN_LEVEL_SEQUENCE entries are
 * (row u8, exposure u32).  Both are checked whole before anything runs. */
static void do_run_sequence(uint8_t graded)
{
    uint8_t entry = graded ? 5 : 8, key = graded ? 1 : 4;
    if (frame.len < 5)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    uint32_t gap_us = get_u32(frame.payload);
    uint8_t count = frame.payload[4];
    if (count == 0 || count > MAX_SEQUENCE)
        return nak(NAK_SEQUENCE_LENGTH, count, 1);
    if (frame.len != 5 + entry * count)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    if (gap_us > MAX_GAP_US)
        return nak(NAK_GAP_RANGE, gap_us, 1);
    const uint8_t *e0 = frame.payload + 5;
    for (uint8_t k = 0; k < count; k++) {
        if (graded && e0[entry * k] >= MAX_SEQUENCE)
            return nak(NAK_ROW_RANGE, e0[entry * k], 1);
    }
    for (uint8_t k = 0; k < count; k++) {
        uint32_t e = get_u32(e0 + entry * k + key);
        if (!exposure_in_range(e))
            return nak(NAK_EXPOSURE_RANGE, e, 1);
    }
    for (uint8_t k = 0; k < count; k++) {
        if (graded)
            sequence.row[k] = e0[entry * k];
        else
            sequence.word[k] = get_u32(e0 + entry * k);
        sequence.exposure_us[k] = get_u32(e0 + entry * k + key);
    }
    sequence.graded = graded;
    sequence.running = 1;
    sequence.seq = frame.seq;
    sequence.count = count;
    sequence.started = 0;
    sequence.done = 0;
    sequence.gap_us = gap_us;
    sequence.waiting = 1;
    sequence.next_us = clock_us(); /* the first trigger goes at once */
    uint8_t p[1] = {count};
    reply(frame.cmd | REPLY, p, 1, 1);
}

static void do_all_off(void)
{
    if (frame.len != 0)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    all_off(SEQ_ABORTED_ALL_OFF);
    reply_u32(clock_us());
}

static void do_set_watchdog(void)
{
    if (frame.len != 2)
        return nak(NAK_BAD_LENGTH, frame.len, 1);
    uint16_t ms = get_u16(frame.payload);
    if (ms < WATCHDOG_MIN_MS || ms > WATCHDOG_MAX_MS)
        return nak(NAK_WATCHDOG_RANGE, ms, 1);
    watchdog_ms = ms;
    uint8_t p[2];
    put_u16(p, ms);
    reply(CMD_SET_WATCHDOG | REPLY, p, 2, 1);
}

static void handle_frame(void)
{
    /* any valid frame is host activity, even one that is refused */
    activity_ms = clock_ms();
    silence_handled = 0;

    uint8_t cmd = frame.cmd;
    if (cmd != CMD_IDENTIFY && cmd != CMD_HEARTBEAT && cache_valid && cache_seq == frame.seq &&
        cache_cmd == cmd) {
        link_send(frame.seq, cache_reply_cmd, cache_payload, cache_len);
        return;
    }
    if (sequence.running && cmd != CMD_ALL_OFF && cmd != CMD_HEARTBEAT)
        return nak(NAK_BUSY, sequence.count - sequence.done, 0);

    switch (cmd) {
    case CMD_IDENTIFY:
        return do_identify();
    case CMD_HEARTBEAT:
        return do_heartbeat();
    case CMD_SET_PATTERN:
        return do_set_pattern();
    case CMD_SET_LEVELS:
        return do_set_levels();
    case CMD_SET_LEVEL_TABLE:
        return do_set_level_table();
    case CMD_RUN_LEVEL_SEQUENCE:
        return do_run_sequence(1);
    case CMD_FIRE:
        return do_fire();
    case CMD_RUN_SEQUENCE:
        return do_run_sequence(0);
    case CMD_ALL_OFF:
        return do_all_off();
    case CMD_SET_WATCHDOG:
        return do_set_watchdog();
    default:
        return nak(NAK_UNKNOWN_COMMAND, cmd, 1);
    }
}

static void service_exposure_end(void)
{
    uint32_t t_trigger, t_end;
    if (!exposure_take_finished(&t_trigger, &t_end))
        return;
    lit = 0;
    activity_ms = clock_ms(); /* the watchdog counts from the end of an exposure too */
    silence_handled = 0;
    uint8_t p[9];
    if (fire_pending) {
        fire_pending = 0;
        put_u32(p, t_trigger);
        put_u32(p + 4, t_end);
        frame.seq = fire_seq;
        frame.cmd = CMD_FIRE;
        reply(CMD_FIRE | REPLY, p, 8, 1);
    } else if (sequence.running) {
        p[0] = sequence.done;
        put_u32(p + 1, t_trigger);
        put_u32(p + 5, t_end);
        link_send(sequence.seq, EVT_TRIGGER, p, 9);
        sequence.done++;
        if (sequence.done == sequence.count) {
            sequence_finish(SEQ_COMPLETE);
        } else {
            sequence.waiting = 1;
            sequence.next_us = t_end + sequence.gap_us;
        }
    }
}

/* Returns 1 when the next trigger is close enough to wait for it awake. */
static uint8_t service_sequence(void)
{
    if (!sequence.running || !sequence.waiting)
        return 0;
    int32_t left = (int32_t)(sequence.next_us - clock_us());
    if (left > 0)
        return left < 2000;
    uint8_t k = sequence.started++;
    sequence.waiting = 0;
    if (sequence.graded) {
        const uint8_t *levels = level_table[sequence.row[k]];
        lit = 0;
        for (uint8_t i = 0; i < LED_COUNT; i++)
            if (levels[i])
                lit |= 1UL << i;
        exposure_start(levels, 0, sequence.exposure_us[k]);
    } else {
        lit = sequence.word[k];
        exposure_start(0, sequence.word[k], sequence.exposure_us[k]);
    }
    return 1;
}

static void service_watchdog(void)
{
    /* Armed only while there is something to switch off: a lit LED, an armed pattern or
     * a sequence; it trips once per silence, never during an exposure. */
    if (silence_handled || exposure_running() || !(lit || armed || sequence.running))
        return;
    if (clock_ms() - activity_ms < watchdog_ms)
        return;
    silence_handled = 1;
    tripped_since_heartbeat = 1;
    all_off(SEQ_ABORTED_WATCHDOG);
    uint8_t p[4];
    put_u32(p, clock_us());
    link_send(0, EVT_WATCHDOG, p, 4);
}

uint8_t stage_poll(void)
{
    uint8_t busy = exposure_poll();
    service_exposure_end();
    /* While a FIRE's exposure runs the host waits for its reply (stop-and-wait): later
     * bytes stay in the receive ring until the reply has gone out. */
    if (!fire_pending) {
        uint16_t crc_received;
        uint8_t got = link_poll(&frame, &crc_received);
        if (got == LINK_FRAME) {
            handle_frame();
            busy = 1;
        } else if (got == LINK_BAD_CRC) {
            nak(NAK_BAD_CRC, crc_received, 0);
            busy = 1;
        }
    }
    busy |= service_sequence();
    service_watchdog();
    return busy;
}
