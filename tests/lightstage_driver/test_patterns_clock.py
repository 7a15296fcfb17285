"""Host-side checks of patterns and exposures, and the firmware clock mapping."""
import math

import numpy as np
import pytest

from lightstage_driver.clock import FirmwareClock
from lightstage_driver.errors import PatternError
from lightstage_driver.patterns import (pattern_levels, pattern_word, validate_exposure, validate_patterns,
                                        word_pattern)


def test_site_major_word():
    pattern = np.zeros(32)
    pattern[2 * 4 + 3] = 1.0      # site 2, NIR
    pattern[0] = 0.6              # site 0, red, above the on/off threshold
    pattern[1] = 0.5              # exactly 0.5 stays off
    assert pattern_word(pattern) == (1 << 11) | 1
    assert np.array_equal(word_pattern(pattern_word(pattern)), (pattern > 0.5).astype(float))
    assert pattern_levels(np.full(32, 0.5), 8) == [128] * 32
    assert pattern_levels(np.ones(32), 12) == [4095] * 32


@pytest.mark.parametrize('patterns, match', [
    (np.zeros(31), 'exactly 32 LED values'),
    (np.zeros((2, 33)), 'exactly 32'),
    (np.zeros((0, 32)), 'no patterns'),
    ([[math.nan] + [0] * 31], r'pattern 0, LED 0 \(site 0, channel 0\) is NaN'),
    ([[0] * 32, [0] * 5 + [-0.1] + [0] * 26], r'pattern 1, LED 5 \(site 1, channel 1\) is negative: -0.1'),
    ([[0] * 31 + [1.5]], r'LED 31 \(site 7, channel 3\) is above 1: 1.5'),
    ([[0] * 31 + [math.inf]], 'infinite'),
    ('lots', 'must be numbers'),
])
def test_bad_patterns_are_named(patterns, match):
    with pytest.raises(PatternError, match=match):
        validate_patterns(patterns)


@pytest.mark.parametrize('value, match', [
    (10, 'exposure_us 10 us is outside the firmware range 20..2000000'),
    (2_000_001, 'outside'),
    (100.5, 'whole number'),
    (math.nan, 'whole number'),
    ('30000', 'must be a number'),
    (True, 'must be a number'),
])
def test_bad_exposures_are_named(value, match):
    with pytest.raises(PatternError, match=match):
        validate_exposure(value, 20, 2_000_000)
    assert validate_exposure(30000.0, 20, 2_000_000) == 30000


def test_clock_unwraps_across_the_32_bit_wrap():
    clock = FirmwareClock()
    assert clock.unwrap(2**32 - 100) == 2**32 - 100
    assert clock.unwrap(50) == 2**32 + 50                # wrapped forward
    assert clock.unwrap(2**32 - 10) == 2**32 - 10        # a slightly older stamp, not a new lap
    assert clock.unwrap(60) == 2**32 + 60


def test_clock_maps_with_the_tightest_probe():
    clock = FirmwareClock()
    # firmware time 1 s == host 101 s; a slow probe (queued) and a fast one
    clock.add_probe(100.990, 1_000_000 - 10_000 + 5_000, 101.0)     # rtt 10 ms, skewed
    clock.add_probe(101.4999, 1_500_000, 101.5001)                  # rtt 0.2 ms
    assert clock.uncertainty_s == pytest.approx(1e-4)
    assert clock.to_host(2_000_000) == pytest.approx(102.0, abs=1e-6)


def test_sim_urls():
    from lightstage_driver.sim_backend import backend_from_url, is_sim_url
    assert is_sim_url('sim') and is_sim_url('sim://?pwm_bits=8') and not is_sim_url('/dev/ttyACM0')
    backend = backend_from_url('sim://?pwm_bits=12&latency_ms=2.5')
    assert '--pwm-bits' in backend.options and '12' in backend.options and '2.5' in backend.options
    backend.close()
    with pytest.raises(ValueError, match=r"unknown simulator option\(s\) \['pwm'\]"):
        backend_from_url('sim://?pwm=8')
    with pytest.raises(ValueError, match='bad simulator option'):
        backend_from_url('sim://?pwm_bits=eight')
    with pytest.raises(ValueError, match='pwm_bits must be 0'):
        backend_from_url('sim://?pwm_bits=7')
