"""Graded patterns through the host API (`LightStage`): levels on boards that grade, a clear
refusal on on/off boards, the applied (rounded) drives on every trigger, and each LED's
on-time on the pins (the Python model's and the compiled firmware's)."""
import os

import numpy as np
import pytest

from lightstage_driver import schedule as sched
from lightstage_driver.errors import PatternError
from lightstage_driver.sim_backend import PythonSimBackend
from lightstage_driver.stage import LightStage

from helpers.driver import wait_until

from helpers.graded_pins import on_times_us

pytestmark = pytest.mark.process

# off-instants are placed on 0.5 us ticks, at least one shift-out apart (schedule.py)
TOLERANCE_US = 0.5 + sched.SHIFT_TICKS / sched.TICKS_PER_US


def avr_backend():
    from lightstage_driver.simavr_backend import SimavrBackend, missing_tools
    missing = missing_tools()
    if missing:
        reason = f'AVR toolchain / simavr not available: missing {", ".join(missing)}'
        if os.environ.get('LIGHTSTAGE_REQUIRE_AVR'):     # `make test`: a failure, not a skip
            pytest.fail(reason)
        pytest.skip(reason)
    return SimavrBackend()


@pytest.fixture(scope='module', params=['python', 'avr'])
def graded(request):
    backend = PythonSimBackend(pwm_bits=8) if request.param == 'python' else avr_backend()
    backend.start()
    yield backend
    backend.close()


def graded_patterns(rng, n):
    patterns = rng.choice([0.0, 1.0, 0.5, 0.25, 0.6], size=(n, 32))
    patterns[:, ::5] = rng.random((n, 7))          # anything in between too
    return patterns


def test_graded_patterns_run_as_level_sequences_with_their_on_times(graded):
    rng = np.random.default_rng(4)
    patterns = graded_patterns(rng, 20)             # a 16-entry sequence, then 4
    patterns[7] = patterns[3]                       # a repeated pattern shares a table row
    exposures = [int(e) for e in rng.integers(200, 8000, size=20)]
    seen = []
    with LightStage(graded.port) as stage:
        assert stage.identity.pwm_bits == 8
        graded.reset_observations()
        triggers = stage.apply(patterns, exposures, on_trigger=seen.append)
        assert [t.index for t in triggers] == list(range(20)) == [t.index for t in seen]
        assert [t.exposure_us for t in triggers] == exposures
        applied = np.array([t.applied for t in triggers])
        # the board's steps: round(drive * 255) / 255
        assert np.array_equal(applied, np.rint(patterns * 255) / 255)
        assert wait_until(lambda: len(graded.trigger_pulses()) == 20, 3.0)
        ons = on_times_us(graded.led_words(), graded.trigger_pulses())
        for k, on in enumerate(ons):
            err = on - applied[k] * exposures[k]
            assert np.abs(err).max() <= TOLERANCE_US, (k, np.round(err, 2).tolist())
        assert graded.led_words()[-1].word == 0 and not stage.heartbeat().leds_lit


def test_one_graded_pattern_is_set_levels_and_fire(graded):
    pattern = np.zeros(32)
    pattern[[0, 5, 31]] = [0.5, 1.0, 0.2]
    with LightStage(graded.port) as stage:
        graded.reset_observations()
        (trigger,) = stage.apply(pattern, 4000)
        assert trigger.applied[0] == 128 / 255 and trigger.applied[31] == 51 / 255
        assert wait_until(lambda: len(graded.trigger_pulses()) == 1, 2.0)
        (on,) = on_times_us(graded.led_words(), graded.trigger_pulses())
        assert np.abs(on - np.array(trigger.applied) * 4000).max() <= TOLERANCE_US


def test_on_off_board_refuses_graded_drives_naming_them():
    with PythonSimBackend(pwm_bits=0) as backend, LightStage(backend.port) as stage:
        pattern = np.zeros(32)
        pattern[9] = 0.7
        with pytest.raises(PatternError, match=r'pattern 0, LED 9 \(site 2, channel 1\) is 0.7, a graded '
                                               r'level, but the board .* on/off only \(pwm_bits 0\)'):
            stage.apply(pattern, 1000)
        with pytest.raises(PatternError, match='on/off only'):
            stage.set_pattern(pattern)
        # 0 and 1 still work, and the refusals sent nothing
        assert backend.led_words() == []
        pattern[9] = 1.0
        (trigger,) = stage.apply(pattern, 1000)
        assert trigger.applied[9] == 1.0 and trigger.word == 1 << 9


def test_twelve_bit_levels_fire_one_pattern_at_a_time():
    """A board with 12-bit levels has no 8-bit level table: SET_LEVELS + FIRE per pattern."""
    with PythonSimBackend(pwm_bits=12) as backend, LightStage(backend.port) as stage:
        patterns = np.full((3, 32), 0.5)
        triggers = stage.apply(patterns, [1000, 2000, 3000])
        assert [t.applied[0] for t in triggers] == [2048 / 4095] * 3
        assert wait_until(lambda: len(backend.trigger_pulses()) == 3, 2.0)
        for trigger, on in zip(triggers, on_times_us(backend.led_words(), backend.trigger_pulses())):
            assert np.abs(on - 2048 / 4095 * trigger.exposure_us).max() <= TOLERANCE_US
