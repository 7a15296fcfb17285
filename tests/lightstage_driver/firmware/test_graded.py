"""Graded levels on the compiled firmware's pins (simavr): each LED lit from the trigger's
rising edge for level / 255 of the exposure, within one timer tick plus one shift-out
(docs/PROTOCOL.md, "Graded levels"); the trigger pulse unchanged; every LED dark after the
exposure; a 16-pattern graded sequence from the level table."""
import numpy as np

from lightstage_driver import protocol as p
from lightstage_driver import schedule as sched

from helpers.graded_pins import on_times_us

C = p.Command
CYCLES_PER_US = 16
TICK_US = 0.5
SHIFT_OUT_US = sched.SHIFT_TICKS / sched.TICKS_PER_US
TOLERANCE_US = TICK_US + SHIFT_OUT_US


def random_levels(rng):
    # zeros, full scale, neighbours and anything in between
    kind = rng.integers(0, 4, size=32)
    levels = rng.integers(1, 255, size=32)
    levels[kind == 0] = 0
    levels[kind == 1] = 255
    return [int(v) for v in levels]


def check_pulse(levels, exposure_us, on_us, width_cycles):
    assert abs(width_cycles - exposure_us * CYCLES_PER_US) < 8, (exposure_us, width_cycles)
    ideal = np.array(levels) / 255 * exposure_us
    err = on_us - ideal
    assert np.all(np.abs(err) <= TOLERANCE_US), (exposure_us, levels, np.round(err, 2).tolist())


def test_fire_lights_each_led_for_its_level_of_the_exposure(avr, wire):
    rng = np.random.default_rng(25)
    # the minimum, the synchronous path's limit, the interrupt path, 16-bit counter wraps,
    # long exposures; two random ones
    exposures = [20, 57, 100, 101, 128, 500, 2000, 9000, 40000, 70001, 250_000,
                 int(rng.integers(20, 5000)), int(rng.integers(5000, 2_000_000))]
    cases = []
    for exposure in exposures:
        levels = random_levels(rng)
        wire.expect_ok(C.SET_LEVELS, p.pack_set_levels(levels, False))
        t_trigger, t_end = wire.fire(exposure)
        assert (t_end - t_trigger) % 2**32 == exposure
        cases.append((levels, exposure))
    assert avr.wait_for(lambda w, pl: len(pl) >= len(cases), 3.0)
    pulses = avr.trigger_pulses()
    cycles = avr.trigger_pulse_cycles()
    words = avr.led_words()
    for (levels, exposure), on, (rise, fall) in zip(cases, on_times_us(words, pulses), cycles):
        check_pulse(levels, exposure, on, fall - rise)
        # the words latched are the schedule's, the last one all dark at the falling edge
        during = [w for w in words if rise <= round(w.time_s * 16e6) <= fall]
        schedule = sched.build(levels, exposure * sched.TICKS_PER_US)
        assert [w.word for w in during] == [schedule.rise_word] + [w for _, w in schedule.steps] + [0]
        assert round(during[-1].time_s * 16e6) == fall
    assert words[-1].word == 0 and not wire.heartbeat().leds_lit


def test_show_now_levels_light_every_level_above_zero(avr, wire):
    levels = [0, 1, 128, 255] * 8
    wire.expect_ok(C.SET_LEVELS, p.pack_set_levels(levels, True))
    assert avr.wait_for(lambda w, pl: len(w) >= 1, 1.0)
    assert avr.led_words()[-1].word == sum(1 << i for i, v in enumerate(levels) if v)
    wire.expect_ok(C.ALL_OFF)


def test_sixteen_graded_patterns_run_as_one_sequence(avr, wire):
    rng = np.random.default_rng(16)
    rows = [random_levels(rng) for _ in range(16)]
    for first in range(0, 16, 4):
        assert wire.expect_ok(C.SET_LEVEL_TABLE, p.pack_level_table(first, rows[first:first + 4])) == \
            bytes((first, 4))
    order = [int(k) for k in rng.permutation(16)]
    exposures = [int(e) for e in rng.integers(20, 6000, size=16)]
    entries = [p.LevelSequenceEntry(row, e) for row, e in zip(order, exposures)]
    seq = wire.send(C.RUN_LEVEL_SEQUENCE, p.pack_level_sequence(200, entries))
    assert wire.reply_to(seq).payload == bytes([16])
    events = [p.TriggerEvent.unpack(wire.event(p.Event.TRIGGER, timeout_s=2.0).payload) for _ in range(16)]
    done = p.SequenceDone.unpack(wire.event(p.Event.SEQUENCE_DONE, timeout_s=2.0).payload)
    assert done == p.SequenceDone(16, p.SequenceStatus.COMPLETE)
    assert [e.index for e in events] == list(range(16))
    assert [(e.t_end_us - e.t_trigger_us) % 2**32 for e in events] == exposures
    assert avr.wait_for(lambda w, pl: len(pl) >= 16, 2.0)
    ons = on_times_us(avr.led_words(), avr.trigger_pulses())
    for row, exposure, on, (rise, fall) in zip(order, exposures, ons, avr.trigger_pulse_cycles()):
        check_pulse(rows[row], exposure, on, fall - rise)
    assert avr.led_words()[-1].word == 0
    # the armed pattern (none) is untouched: a FIRE now lights nothing
    wire.fire(50)
    assert avr.wait_for(lambda w, pl: len(pl) >= 17, 1.0)
    assert on_times_us(avr.led_words(), avr.trigger_pulses())[-1].sum() == 0
