"""Checking an ApplyPatterns request field by field before anything is sent (no rclpy).

Every bad value raises `PatternError` naming the field (`patterns[3].gain_db`), the value
and the range, so that the service answers with what to fix and never dies on a request.
"""
from __future__ import annotations

import numpy as np
from lightstage_graph.limits import LimitError, check_gain_db, requested_gain_db

from .errors import PatternError
from .patterns import led_name
from .protocol import LED_COUNT

# More triggers than one call should hold: 1024 x the longest exposure is half an hour.
MAX_PATTERNS_PER_REQUEST = 1024


def check_request(patterns, default_exposure_us: int, min_exposure_us: int, max_exposure_us: int
                  ) -> tuple[np.ndarray, list[int]]:
    """(intensities (k, 32) float64, exposures [us]) of a request's patterns, or PatternError.

    `patterns` are Pattern messages (or anything with intensities, exposure_us, gain_db and
    optionally gain_db_set). exposure_us 0 is the driver's default; gain_db NaN, or 0 with
    gain_db_set false (a field left out), is the camera's gain (`requested_gain_db`).
    """
    if len(patterns) == 0:
        raise PatternError('no patterns in the request: send at least one Pattern')
    if len(patterns) > MAX_PATTERNS_PER_REQUEST:
        raise PatternError(f'patterns holds {len(patterns)} patterns; at most {MAX_PATTERNS_PER_REQUEST} '
                           f'per call: split the request')
    rows = []
    exposures = []
    for k, pattern in enumerate(patterns):
        field = f'patterns[{k}]'
        try:
            row = np.asarray(pattern.intensities, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise PatternError(f'{field}.intensities must be {LED_COUNT} numbers: {exc}') from exc
        if row.ndim != 1:
            raise PatternError(f'{field}.intensities must be a flat list of {LED_COUNT} numbers, got shape '
                               f'{row.shape}')
        if row.shape != (LED_COUNT,):
            raise PatternError(f'{field}.intensities has {row.size} values; it needs exactly {LED_COUNT} '
                               f'(site-major, led = site * 4 + channel)')
        for what, bad in (('NaN', np.isnan(row)), ('infinite', np.isinf(row)), ('negative', row < 0),
                          ('above 1', row > 1)):
            if bad.any():
                led = int(np.flatnonzero(bad)[0])
                raise PatternError(f'{field}.intensities[{led}]: pattern {k}, {led_name(led)} is '
                                   f'{what}: {row[led]:.7g}; LED drives must be in [0, 1]')
        rows.append(row)
        exposure = pattern.exposure_us
        if isinstance(exposure, bool) or not isinstance(exposure, (int, np.integer)):
            raise PatternError(f'{field}.exposure_us must be a whole number of microseconds, got {exposure!r}')
        exposure = int(exposure) or int(default_exposure_us)
        if not min_exposure_us <= exposure <= max_exposure_us:
            raise PatternError(f'{field}.exposure_us {int(pattern.exposure_us)} us is outside the firmware '
                               f'range {min_exposure_us}..{max_exposure_us} us (0 = the driver default, '
                               f'{int(default_exposure_us)} us)')
        exposures.append(exposure)
        try:  # the camera checks the same range (lightstage_graph.limits) again
            check_gain_db(pattern.gain_db, f'{field}.gain_db', nan_is_default=True)
            check_gain_db(requested_gain_db(pattern.gain_db, getattr(pattern, 'gain_db_set', False)),
                          f'{field}.gain_db', nan_is_default=True)
        except LimitError as exc:
            raise PatternError(str(exc)) from None
    return np.array(rows), exposures


def rounding_note(requested: np.ndarray, applied: list, pwm_bits: int) -> str:
    """What rounding to the board's level steps changed, for the service reply ('' if nothing)."""
    if not applied or not pwm_bits:
        return ''
    diff = np.abs(np.asarray(applied, dtype=np.float64) - requested[:len(applied)])
    worst = float(diff.max())
    if worst < 1e-9:
        return ''
    k, led = map(int, np.unravel_index(int(diff.argmax()), diff.shape))
    return (f'; drives rounded to the board\'s {pwm_bits}-bit levels (1/{(1 << pwm_bits) - 1} steps), '
            f'largest change {worst:.4f} at pattern {k} LED {led}; /illumination carries the applied drives')
