"""The Classify request contract the node and `lightstage classify` share."""
import math
import threading

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mux_classifier.classify_request import (MAX_IMAGES_MAX, TIMEOUT_MAX_S, TIMEOUT_MIN_S,
                                             request_max_images, request_timeout_s)


def test_zero_is_the_default_and_the_range_is_kept():
    assert request_timeout_s(0.0, 10.0) == 10.0 and request_timeout_s(-0.0, 7.5) == 7.5
    assert request_timeout_s(0.0) == 0.0
    assert request_timeout_s(TIMEOUT_MIN_S, 10.0) == TIMEOUT_MIN_S
    assert request_timeout_s(TIMEOUT_MAX_S, 10.0) == TIMEOUT_MAX_S
    assert TIMEOUT_MAX_S < threading.TIMEOUT_MAX


@pytest.mark.parametrize('bad', [-1.0, math.nan, math.inf, -math.inf, 1e-6, 0.0999, 600.001,
                                 1e10, 'ten', None])
def test_other_time_limits_are_refused_naming_the_value(bad):
    with pytest.raises(ValueError, match=r"timeout_s must be 0 \(the classifier node's default\) "
                                         rf"or between 0.1 and 600 s; got {repr(bad)}$"):
        request_timeout_s(bad, 10.0)


@given(st.floats())
def test_any_float_gives_a_time_limit_in_range_or_a_refusal(value):
    try:
        limit = request_timeout_s(value, 10.0)
    except ValueError as exc:
        assert repr(value) in str(exc)
        return
    assert TIMEOUT_MIN_S <= limit <= TIMEOUT_MAX_S


def test_max_images_is_a_uint32():
    assert request_max_images(0) == 0 and request_max_images(MAX_IMAGES_MAX) == MAX_IMAGES_MAX
    for bad in [-1, MAX_IMAGES_MAX + 1, 4.0, True]:
        with pytest.raises(ValueError, match=r'max_images must be an integer from 0'):
            request_max_images(bad)
