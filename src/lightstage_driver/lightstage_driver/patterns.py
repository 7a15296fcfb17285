"""Checking LED patterns and exposures before anything is sent to the stage.

An LED pattern is a length-32 vector of relative drives in [0, 1], site-major
(`led = site * 4 + channel`). A board with graded levels (`pwm_bits` > 0) gets them
rounded to its steps (level = round(drive * (2^pwm_bits - 1)), an on-time of level /
full scale of the exposure); an on/off board takes only 0 and 1 and refuses anything in
between (`check_on_off`) rather than thresholding it. Every check raises `PatternError`
naming the offending value; nothing is sent on error.
"""
from __future__ import annotations

import math

import numpy as np
from lightstage_graph.leds import site_and_channel

from .errors import PatternError
from .protocol import LED_COUNT

ON_THRESHOLD = 0.5


def led_name(led: int) -> str:
    """'LED 13 (site 3, channel 1)': an LED of a pattern as the error messages name it."""
    site, channel = site_and_channel(led)
    return f'LED {led} (site {site}, channel {channel})'


def validate_patterns(patterns, led_count: int = LED_COUNT) -> np.ndarray:
    """Return the patterns as a float64 `(k, led_count)` array, or raise PatternError.

    Accepts one pattern (length `led_count`) or a sequence/array of them.
    """
    try:
        array = np.asarray(patterns, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PatternError(f'patterns must be numbers, shape (k, {led_count}): {exc}') from exc
    if array.ndim == 1:
        array = array[None, :]
    if array.ndim != 2 or array.shape[1] != led_count:
        raise PatternError(f'a pattern needs exactly {led_count} LED values (site-major, '
                           f'led = site * 4 + channel); got shape {np.shape(patterns)}')
    if array.shape[0] == 0:
        raise PatternError('no patterns given: send at least one')
    for what, bad in (('NaN', np.isnan(array)), ('infinite', np.isinf(array)),
                      ('negative', array < 0), ('above 1', array > 1)):
        if bad.any():
            k, led = map(int, np.argwhere(bad)[0])
            raise PatternError(f'pattern {k}, {led_name(led)} is {what}: '
                               f'{float(array[k, led])!r}; LED drives must be in [0, 1]')
    return array


def check_on_off(array: np.ndarray, board: str) -> None:
    """Refuse graded drives for an on/off board (pwm_bits 0): every value must be 0 or 1."""
    graded = (array != 0) & (array != 1)
    if graded.any():
        k, led = map(int, np.argwhere(graded)[0])
        raise PatternError(f'pattern {k}, {led_name(led)} is '
                           f'{float(array[k, led])!r}, a graded level, but {board} switches LEDs '
                           f'on/off only (pwm_bits 0): send 0 or 1, or use firmware with graded '
                           f'levels (pwm_bits 8, firmware 1.1 or later)')


def applied_drives(pattern: np.ndarray, pwm_bits: int) -> np.ndarray:
    """The drives a board actually applies: rounded to its level steps (0/1 when on/off)."""
    if not pwm_bits:
        return np.asarray(pattern > ON_THRESHOLD, dtype=np.float64)
    full = (1 << pwm_bits) - 1
    return np.array(pattern_levels(pattern, pwm_bits), dtype=np.float64) / full


def pattern_word(pattern: np.ndarray) -> int:
    """32-bit LED word of one validated pattern (bit i = LED i on)."""
    bits = np.flatnonzero(np.asarray(pattern) > ON_THRESHOLD)
    return int(sum(1 << int(i) for i in bits))


def word_pattern(word: int, led_count: int = LED_COUNT) -> np.ndarray:
    """Inverse of `pattern_word`: a 0/1 float vector."""
    return np.array([(word >> i) & 1 for i in range(led_count)], dtype=np.float64)


def pattern_levels(pattern: np.ndarray, pwm_bits: int) -> list[int]:
    """PWM levels 0..2^pwm_bits - 1 of one validated pattern."""
    full = (1 << pwm_bits) - 1
    return [int(v) for v in np.rint(np.asarray(pattern) * full)]


def lit_word(pattern: np.ndarray, pwm_bits: int) -> int:
    """LED word of the LEDs that will actually light (on/off: above 0.5; PWM: level > 0)."""
    if not pwm_bits:
        return pattern_word(pattern)
    return sum(1 << i for i, level in enumerate(pattern_levels(pattern, pwm_bits)) if level > 0)


def validate_exposure(exposure_us, min_us: int, max_us: int, what: str = 'exposure_us') -> int:
    """Return the exposure as an int in [min_us, max_us], or raise PatternError."""
    if isinstance(exposure_us, bool) or not isinstance(exposure_us, (int, float, np.integer, np.floating)):
        raise PatternError(f'{what} must be a number of microseconds, got {exposure_us!r}')
    if isinstance(exposure_us, (float, np.floating)):
        if not math.isfinite(exposure_us) or exposure_us != int(exposure_us):
            raise PatternError(f'{what} must be a whole number of microseconds, got {exposure_us!r}')
    value = int(exposure_us)
    if not min_us <= value <= max_us:
        raise PatternError(f'{what} {value} us is outside the firmware range {min_us}..{max_us} us')
    return value
