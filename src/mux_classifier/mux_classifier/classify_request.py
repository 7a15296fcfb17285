"""What a Classify request may ask for: the one definition the classifier node and
`lightstage classify` share.

Standard library only: the CLI checks its arguments with it before it imports anything heavy.
"""
from __future__ import annotations

import math

# A request's time limit, and the node's `timeout_s` parameter: every wait of one
# classification (the stage lock, the driver, the images) must be a valid timeout, and a
# call must end while its client still waits for it. 0 in a request means the node's default.
TIMEOUT_MIN_S = 0.1
TIMEOUT_MAX_S = 600.0
MAX_IMAGES_MAX = 2**32 - 1  # Classify.Request.max_images is a uint32


def request_timeout_s(value, default_s: float | None = None, name: str = 'timeout_s') -> float:
    """The time limit [s] a request's ``timeout_s`` asks for; 0 gives ``default_s``.

    Anything other than 0 or a number in [TIMEOUT_MIN_S, TIMEOUT_MAX_S] (negative, NaN, inf,
    too small to do anything in, too large for a timer) raises ValueError naming the value.
    With ``default_s`` None (a client that does not know the node's default) 0 gives 0.0.
    """
    try:
        seconds = float(value)
    except (TypeError, ValueError, OverflowError):
        seconds = math.nan
    if seconds == 0.0:
        return 0.0 if default_s is None else float(default_s)
    if not TIMEOUT_MIN_S <= seconds <= TIMEOUT_MAX_S:  # also false for NaN
        raise ValueError(f'{name} must be 0 (the classifier node\'s default) or between '
                         f'{TIMEOUT_MIN_S:g} and {TIMEOUT_MAX_S:g} s; got {value!r}')
    return seconds


def request_max_images(value, name: str = 'max_images') -> int:
    """A request's ``max_images`` (0 = all the classifier has); ValueError outside the uint32
    field's range."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_IMAGES_MAX:
        raise ValueError(f'{name} must be an integer from 0 (all the classifier has) to '
                         f'{MAX_IMAGES_MAX}; got {value!r}')
    return value
