"""What the compiled firmware does on its pins, seen by the simavr harness: the LED words
latched into the 74HC595 chain and the camera trigger pulses."""
import numpy as np

from lightstage_driver import protocol as p

CYCLES_PER_US = 16          # 16 MHz
TICK_CYCLES = 8             # Timer1 at F_CPU/8: one tick = 0.5 us


def wait_words(avr, n, timeout_s=2.0):
    assert avr.wait_for(lambda words, pulses: len(words) >= n, timeout_s), avr.led_words()
    return [w.word for w in avr.led_words()]


def test_show_now_latches_every_word_sent_in_order(avr, wire):
    rng = np.random.default_rng(6)
    # bit order: single LEDs at both ends of the chain, all on, all off, then random words
    sent = [1, 1 << 31, 1 << 4, 0xFFFFFFFF, 0, 0x0000000F, 0xF0000000] + \
        [int(w) for w in rng.integers(0, 2**32, size=25, dtype=np.uint64)]
    for word in sent:
        wire.set_pattern(word, show_now=True)
    assert wait_words(avr, len(sent)) == sent
    assert not avr.trigger_pulses()


def test_set_pattern_without_show_now_changes_no_led_until_fire(avr, wire):
    wire.set_pattern(0x00A5_5A00, show_now=False)
    assert wire.heartbeat().leds_lit is False
    assert avr.led_words() == []
    t_trigger, t_end = wire.fire(200)
    words = wait_words(avr, 2)
    assert words == [0x00A5_5A00, 0]
    assert t_end - t_trigger == 200
    # the armed pattern stays armed for the next FIRE
    wire.fire(100)
    assert wait_words(avr, 4)[2:] == [0x00A5_5A00, 0]


def test_fire_latch_edges_coincide_with_trigger_edges(avr, wire):
    """On the authors' pins (latch D11, trigger D8, both port B) one instruction switches
    both: the LEDs are lit for exactly the trigger pulse."""
    wire.set_pattern(0x1234_5678, show_now=False)
    wire.fire(1000)
    assert avr.wait_for(lambda w, pl: len(w) >= 2 and len(pl) >= 1, 1.0)
    words = avr.led_words()
    (rise, fall), = avr.trigger_pulse_cycles()
    assert [w.word for w in words] == [0x1234_5678, 0]
    assert round(words[0].time_s * 16e6) == rise
    assert round(words[1].time_s * 16e6) == fall


def test_trigger_width_equals_exposure_within_one_timer_tick(avr, wire):
    # the synchronous path (<= 100 us), the interrupt path, one and two 16-bit counter
    # wraps (65536 ticks = 32768 us)
    exposures = [20, 21, 57, 99, 100, 101, 333, 1000, 12345, 32767, 32768, 32769, 70001]
    replies = []
    wire.set_pattern(0x8000_0001, show_now=False)
    for exposure in exposures:
        replies.append(wire.fire(exposure))
    assert avr.wait_for(lambda w, pl: len(pl) >= len(exposures), 2.0)
    pulses = avr.trigger_pulse_cycles()
    widths = [fall - rise for rise, fall in pulses]
    errors = [width - exposure * CYCLES_PER_US for width, exposure in zip(widths, exposures)]
    assert all(abs(e) < TICK_CYCLES for e in errors), list(zip(exposures, errors))
    for (t_trigger, t_end), exposure in zip(replies, exposures):
        assert (t_end - t_trigger) % 2**32 == exposure
    # the firmware's clock agrees with the pins: trigger times advance like the cycles
    for k in range(1, len(exposures)):
        firmware_dt = (replies[k][0] - replies[0][0]) % 2**32
        pin_dt = (pulses[k][0] - pulses[0][0]) / CYCLES_PER_US
        assert abs(firmware_dt - pin_dt) <= 1.0


def test_sequence_on_the_pins(avr, wire):
    words = [0x1, 0x10, 0x100, 0xFFFF_0000, 0x8000_0000]
    exposures = [20, 150, 1000, 40000, 500]
    gap_us = 300
    entries = [p.SequenceEntry(w, e) for w, e in zip(words, exposures)]
    seq = wire.send(p.Command.RUN_SEQUENCE, p.pack_sequence(gap_us, entries))
    assert wire.reply_to(seq).payload == bytes([len(words)])
    events = [p.TriggerEvent.unpack(wire.event(p.Event.TRIGGER).payload) for _ in words]
    done = p.SequenceDone.unpack(wire.event(p.Event.SEQUENCE_DONE).payload)
    assert done == p.SequenceDone(len(words), p.SequenceStatus.COMPLETE)
    assert [e.index for e in events] == list(range(len(words)))
    assert [(e.t_end_us - e.t_trigger_us) for e in events] == exposures
    assert avr.wait_for(lambda w, pl: len(pl) >= len(words), 1.0)
    pulses = avr.trigger_pulse_cycles()
    assert wait_words(avr, 2 * len(words)) == [x for w in words for x in (w, 0)]
    for (rise, fall), exposure in zip(pulses, exposures):
        assert abs(fall - rise - exposure * CYCLES_PER_US) < TICK_CYCLES
    dark_us = [(pulses[k + 1][0] - pulses[k][1]) / CYCLES_PER_US for k in range(len(words) - 1)]
    # at least the gap; stretched by at most the event's transmission (<= 2 ms)
    assert all(gap_us <= d <= gap_us + 2000 for d in dark_us), dark_us
    # the armed pattern is untouched by a sequence
    wire.set_pattern(0x0F0F, show_now=False)
    avr.reset_observations()
    seq = wire.send(p.Command.RUN_SEQUENCE, p.pack_sequence(0, [p.SequenceEntry(0xF0, 50)]))
    wire.reply_to(seq)
    wire.event(p.Event.SEQUENCE_DONE)
    wire.fire(50)
    assert wait_words(avr, 4) == [0xF0, 0, 0x0F0F, 0]


def test_all_off_aborts_a_sequence_at_once(avr, wire):
    entries = [p.SequenceEntry(0xFFFF_FFFF, 200_000)] * 3
    seq = wire.send(p.Command.RUN_SEQUENCE, p.pack_sequence(0, entries))
    wire.reply_to(seq)
    assert avr.wait_for(lambda w, pl: len(w) >= 1, 1.0)   # first exposure under way
    # only ALL_OFF and HEARTBEAT are served while a sequence runs
    status = wire.heartbeat()
    assert status.sequence_running and status.leds_lit
    nak = wire.expect_nak(p.Command.SET_PATTERN, p.pack_set_pattern(1, True))
    assert (nak.reason, nak.value) == (p.NakReason.BUSY, 3)
    off_seq = wire.send(p.Command.ALL_OFF)
    done = wire.event(p.Event.SEQUENCE_DONE)
    assert p.SequenceDone.unpack(done.payload) == p.SequenceDone(0, p.SequenceStatus.ABORTED_BY_ALL_OFF)
    assert wire.reply_to(off_seq).cmd == p.Command.ALL_OFF | p.REPLY_BIT
    assert avr.wait_for(lambda w, pl: len(pl) >= 1, 1.0)
    (rise, fall), = avr.trigger_pulse_cycles()
    assert (fall - rise) < 200_000 * CYCLES_PER_US      # cut short
    assert [w.word for w in avr.led_words()] == [0xFFFF_FFFF, 0]
    assert round(avr.led_words()[-1].time_s * 16e6) >= fall
    assert not wire.heartbeat().sequence_running
