"""The protocol's host watchdog in the compiled firmware: the LEDs go dark after the
configured silence, measured on the pins in simulated time."""
import time

import pytest

from lightstage_driver import protocol as p

CYCLES_PER_MS = 16_000


def zero_latch_after(avr, cycle):
    for w in avr.led_words():
        if round(w.time_s * 16e6) > cycle and w.word == 0:
            return round(w.time_s * 16e6)
    return None


@pytest.mark.parametrize('timeout_ms', [50, 120])
def test_watchdog_darkens_the_leds_after_the_configured_silence(avr, wire, timeout_ms):
    assert wire.set_watchdog(timeout_ms) == timeout_ms
    t_lit = wire.set_pattern(0x0F0F_F0F0, show_now=True)
    # silence from here on
    event = wire.event(p.Event.WATCHDOG, timeout_s=2.0)
    t_trip = p.unpack_u32(event.payload, 'EVT_WATCHDOG')
    assert avr.wait_for(lambda w, pl: len(w) >= 2, 1.0)
    lit, dark = avr.led_words()
    assert (lit.word, dark.word) == (0x0F0F_F0F0, 0)
    silence_ms = (dark.time_s - lit.time_s) * 1e3
    # the firmware counts whole milliseconds of its 1 kHz tick
    assert timeout_ms - 1 <= silence_ms <= timeout_ms + 1.5, silence_ms
    assert timeout_ms - 1 <= (t_trip - t_lit) / 1e3 <= timeout_ms + 1.5
    status = wire.heartbeat()
    assert status.watchdog_tripped and not status.leds_lit
    assert not wire.heartbeat().watchdog_tripped     # cleared by the read
    # the armed pattern was cleared too: a FIRE now shows nothing
    avr.reset_observations()
    wire.fire(100)
    assert avr.wait_for(lambda w, pl: len(w) >= 2, 1.0)
    assert [w.word for w in avr.led_words()] == [0, 0]


def test_heartbeats_keep_the_leds_lit(avr, wire):
    wire.set_watchdog(100)
    wire.set_pattern(0x00FF_0000, show_now=True)
    end = time.monotonic() + 0.4
    while time.monotonic() < end:
        wire.heartbeat()
        time.sleep(0.03)
    assert [w.word for w in avr.led_words()] == [0x00FF_0000]
    assert not any(f.cmd == p.Event.WATCHDOG for f in wire.drain())
    # one event per silence
    wire.event(p.Event.WATCHDOG, timeout_s=1.0)
    time.sleep(0.25)
    assert not any(f.cmd == p.Event.WATCHDOG for f in wire.drain())
    assert [w.word for w in avr.led_words()] == [0x00FF_0000, 0]


def test_watchdog_waits_for_the_end_of_a_long_exposure(avr, wire):
    """Silence is counted from the end of the last exposure, not from the FIRE command.
    (300 ms is also longer than the AVR's own 250 ms watchdog timer, which must not reset
    the chip while it waits.)"""
    wire.set_watchdog(50)
    wire.set_pattern(0x3, show_now=False)
    t_trigger, t_end = wire.fire(300_000)          # six times the host watchdog timeout
    assert t_end - t_trigger == 300_000
    event = wire.event(p.Event.WATCHDOG, timeout_s=1.0)
    t_trip = p.unpack_u32(event.payload, 'EVT_WATCHDOG')
    assert 49 <= (t_trip - t_end) / 1e3 <= 51.5
    (rise, fall), = avr.trigger_pulse_cycles()
    assert abs((fall - rise) - 300_000 * 16) < 8    # the exposure was not cut short
    assert not [f for f in wire.drain() if f.cmd == p.Event.READY]   # no reboot


def test_watchdog_aborts_a_sequence(avr, wire):
    wire.set_watchdog(50)
    # each exposure's end restarts the count: 40 ms gaps keep a silent host's sequence
    # running, a 100 ms gap does not
    entries = [p.SequenceEntry(0xFF, 5_000)] * 3
    seq = wire.send(p.Command.RUN_SEQUENCE, p.pack_sequence(40_000, entries))
    wire.reply_to(seq)
    done = p.SequenceDone.unpack(wire.event(p.Event.SEQUENCE_DONE, timeout_s=2.0).payload)
    assert done == p.SequenceDone(3, p.SequenceStatus.COMPLETE)
    # nothing lit or armed afterwards: the silence trips nothing
    time.sleep(0.1)
    assert not any(f.cmd == p.Event.WATCHDOG for f in wire.drain())
    avr.reset_observations()
    wire.heartbeat()
    seq = wire.send(p.Command.RUN_SEQUENCE, p.pack_sequence(100_000, entries))
    wire.reply_to(seq)
    done = p.SequenceDone.unpack(wire.event(p.Event.SEQUENCE_DONE, timeout_s=2.0).payload)
    assert done == p.SequenceDone(1, p.SequenceStatus.ABORTED_BY_WATCHDOG)
    wire.event(p.Event.WATCHDOG)
    assert len(avr.trigger_pulse_cycles()) == 1
    assert avr.current_word() == 0


def test_watchdog_timeout_range(avr, wire):
    for bad in (0, 49, 60001, 65535):
        nak = wire.expect_nak(p.Command.SET_WATCHDOG, bad.to_bytes(2, 'little'))
        assert (nak.reason, nak.value) == (p.NakReason.WATCHDOG_RANGE, bad)
    assert wire.set_watchdog(60000) == 60000
    identity = p.Identity.unpack(wire.expect_ok(p.Command.IDENTIFY))
    assert identity.watchdog_ms == 60000
