"""Every field of an ApplyPatterns request, fuzzed: the driver's request check either accepts
the request (and then every value is in range) or refuses it with a PatternError naming the
field; it never raises anything else (the node turns a refusal into its reply).

LIGHTSTAGE_FUZZ_EXAMPLES=5000 runs a longer fuzz (default 300 examples).
"""
import math
import os
from types import SimpleNamespace

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lightstage_driver.errors import PatternError
from lightstage_driver.request_check import MAX_PATTERNS_PER_REQUEST, check_request
from lightstage_graph.limits import GAIN_DB_MAX, GAIN_DB_MIN

FUZZ = settings(max_examples=int(os.environ.get('LIGHTSTAGE_FUZZ_EXAMPLES', 300)), deadline=None,
                suppress_health_check=[HealthCheck.too_slow])
MIN_US, MAX_US, DEFAULT_US = 20, 2_000_000, 30_000

SPECIAL_FLOATS = [math.nan, -math.nan, math.inf, -math.inf, -0.0, 0.0, 1.0, 1.0000001, -1e-45,
                  5e-324, 1e300, -1e300, 0.5, 48.0, 48.0001, -0.0001, 3.4e38]
drives = st.floats(allow_nan=True, allow_infinity=True, width=32) | st.sampled_from(SPECIAL_FLOATS)
intensities = (st.lists(drives, min_size=32, max_size=32)
               | st.lists(drives, max_size=40)                     # wrong lengths
               | st.sampled_from([None, 'abc', [[0.0] * 32], [0.0] * 31 + ['x'], 7]))
exposures = (st.integers(0, 2**32 - 1) | st.sampled_from([0, 19, 20, 2_000_000, 2_000_001, -1, 2**64])
             | st.sampled_from([1.5, math.nan, True, None, '100']))
gains = (st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(SPECIAL_FLOATS)
         | st.sampled_from([None, 'loud', 12, True]))
patterns = st.builds(SimpleNamespace, intensities=intensities, exposure_us=exposures, gain_db=gains)


def valid(pattern) -> bool:
    try:
        row = np.asarray(pattern.intensities, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    if row.shape != (32,) or not (np.isfinite(row).all() and (row >= 0).all() and (row <= 1).all()):
        return False
    e = pattern.exposure_us
    if isinstance(e, bool) or not isinstance(e, int) or not MIN_US <= (e or DEFAULT_US) <= MAX_US:
        return False
    g = pattern.gain_db
    if isinstance(g, str) or g is None:
        return False
    g = float(g)
    return math.isnan(g) or GAIN_DB_MIN <= g <= GAIN_DB_MAX


@FUZZ
@given(st.lists(patterns, max_size=4))
def test_every_field_is_checked_and_a_refusal_names_it(request_patterns):
    try:
        array, checked = check_request(request_patterns, DEFAULT_US, MIN_US, MAX_US)
    except PatternError as exc:
        message = str(exc)
        bad = next((k for k, pt in enumerate(request_patterns) if not valid(pt)), None)
        if bad is None:
            assert not request_patterns and 'no patterns' in message
        else:
            assert f'patterns[{bad}].' in message, message
            assert any(field in message for field in ('intensities', 'exposure_us', 'gain_db')), message
        return
    assert request_patterns and all(valid(pt) for pt in request_patterns)
    assert array.shape == (len(request_patterns), 32)
    assert all(MIN_US <= e <= MAX_US for e in checked)


def test_each_field_names_itself():
    good = dict(intensities=[0.5] * 32, exposure_us=1000, gain_db=math.nan)
    cases = [({'intensities': [0.5] * 31}, 'patterns[0].intensities has 31 values'),
             ({'intensities': [math.nan] + [0.0] * 31}, 'patterns[0].intensities[0]: pattern 0, LED 0 (site 0, channel 0) is NaN'),
             ({'intensities': [0.0] * 31 + [math.inf]}, 'patterns[0].intensities[31]: pattern 0, LED 31 (site 7, channel 3) is infinite'),
             ({'intensities': [0.0, -0.1] + [0.0] * 30}, 'patterns[0].intensities[1]: pattern 0, LED 1 (site 0, channel 1) is negative'),
             ({'intensities': [0.0] * 5 + [1.5] + [0.0] * 26}, 'LED 5 (site 1, channel 1) is above 1'),
             ({'exposure_us': 2**32 - 1}, 'patterns[0].exposure_us 4294967295 us is outside the firmware range'),
             ({'exposure_us': 5}, 'patterns[0].exposure_us 5 us is outside'),
             ({'gain_db': math.inf}, 'patterns[0].gain_db = inf dB is out of range: give 0 .. 48 dB'),
             ({'gain_db': -3.0}, 'patterns[0].gain_db = -3.0 dB is out of range'),
             ({'gain_db': 'loud'}, 'patterns[0].gain_db must be a number')]
    for change, expected in cases:
        try:
            check_request([SimpleNamespace(**{**good, **change})], DEFAULT_US, MIN_US, MAX_US)
        except PatternError as exc:
            assert expected in str(exc), (change, str(exc))
        else:
            raise AssertionError(f'{change} was accepted')
    too_many = [SimpleNamespace(**good)] * (MAX_PATTERNS_PER_REQUEST + 1)
    try:
        check_request(too_many, DEFAULT_US, MIN_US, MAX_US)
    except PatternError as exc:
        assert f'at most {MAX_PATTERNS_PER_REQUEST} per call' in str(exc)
    else:
        raise AssertionError('an oversized request was accepted')
    # 0 is the default exposure; NaN the camera's default gain
    array, exposures = check_request([SimpleNamespace(**{**good, 'exposure_us': 0})], DEFAULT_US, MIN_US, MAX_US)
    assert exposures == [DEFAULT_US]
