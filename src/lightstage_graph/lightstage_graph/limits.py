"""The ranges of the camera settings anything may ask for: a pattern of an ApplyPatterns call
(checked by the driver), a trigger reaching the camera node (checked again: it must never
die on a value), an artifact's noise setting, a rig.yaml, a noise file, node parameters.

One place, so that a value one of them takes is taken by all the others:

    GAIN_DB        0 .. 48 dB       (NaN where "the camera's default" is meant; in a
                                    message, 0 too unless its gain_db_set is true)
    EXPOSURE_US    1 .. 10 000 000 us (0 in a pattern: the driver's default)
    DIMMER         0.001 .. 10

The check functions raise `LimitError` (a ValueError) naming the field, the value and the
range. No rclpy here.
"""
from __future__ import annotations

import math
import numbers

__all__ = ["GAIN_DB_MIN", "GAIN_DB_MAX", "EXPOSURE_US_MIN", "EXPOSURE_US_MAX", "DIMMER_MIN",
           "DIMMER_MAX", "LimitError", "check_range", "check_gain_db", "check_exposure_us",
           "check_dimmer", "check_camera_setting", "requested_gain_db", "gain_db_fields"]

# Machine-vision cameras give 0 .. 24-48 dB of analogue plus digital gain; 48 dB is 251 x.
GAIN_DB_MIN, GAIN_DB_MAX = 0.0, 48.0
# 1 us .. 10 s: the firmware's own range (IDENTIFY: 20 .. 2 000 000 us by default) lies inside.
EXPOSURE_US_MIN, EXPOSURE_US_MAX = 1, 10_000_000
# The scale of the single-LED images (the authors' 0.45); beyond these nothing is usable.
DIMMER_MIN, DIMMER_MAX = 0.001, 10.0


class LimitError(ValueError):
    """A setting outside its range or not a number; the message names the field."""


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise LimitError(f"{what} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an int beyond float
        raise LimitError(f"{what} = {value} is far out of range") from None


def number_text(number: float) -> str:
    """A bound as people write it: 10000000, not 1e+07; 0.001, not 1e-03."""
    if float(number).is_integer() and abs(number) < 1e15:
        return str(int(number))
    return f"{number:g}"


def check_range(value, what: str, lo: float, hi: float, unit: str = "") -> float:
    """`value` as a float if it is a finite number in [lo, hi]; else LimitError naming
    `what`, the value and the range."""
    number = _number(value, what)
    if not (math.isfinite(number) and lo <= number <= hi):
        unit = f" {unit}" if unit else ""
        raise LimitError(f"{what} = {value!r}{unit} is out of range: give {number_text(lo)} .. "
                         f"{number_text(hi)}{unit}")
    return number


def _check_or_default(value, what, lo, hi, unit, is_default, default_text) -> float:
    """check_range, except that a value `is_default` accepts passes as it is (and the
    message of a refusal says so)."""
    number = _number(value, what)
    if is_default is not None and is_default(number):
        return number
    try:
        return check_range(value, what, lo, hi, unit)
    except LimitError as exc:
        if is_default is None:
            raise
        raise LimitError(f"{exc} (or {default_text})") from None


def check_gain_db(value, what: str = "gain_db", *, nan_is_default: bool = True) -> float:
    """A gain in dB within GAIN_DB_MIN .. GAIN_DB_MAX; NaN passes (as NaN) where it means
    the camera's default gain (`nan_is_default`). inf, -1e6, 1e6 are refused."""
    return _check_or_default(value, what, GAIN_DB_MIN, GAIN_DB_MAX, "dB",
                             math.isnan if nan_is_default else None,
                             "NaN for the camera's default gain")


def check_exposure_us(value, what: str = "exposure_us", *, zero_is_default: bool = False) -> float:
    """An exposure in us within EXPOSURE_US_MIN .. EXPOSURE_US_MAX; 0 passes where it means
    a default (`zero_is_default`)."""
    return _check_or_default(value, what, EXPOSURE_US_MIN, EXPOSURE_US_MAX, "us",
                             (lambda number: number == 0) if zero_is_default else None,
                             "0 for the default exposure")


def check_dimmer(value, what: str = "dimmer") -> float:
    """A dimmer (scale of the single-LED images) within DIMMER_MIN .. DIMMER_MAX."""
    return check_range(value, what, DIMMER_MIN, DIMMER_MAX)


def check_camera_setting(exposure_us, gain_db) -> None:
    """A camera setting a capture or calibration runs at (and records in rig.yaml / a noise
    file): a whole number of microseconds in range and a gain in range, no defaults."""
    if isinstance(exposure_us, float) and math.isfinite(exposure_us) and not exposure_us.is_integer():
        raise LimitError(f"exposure_us must be a whole number of microseconds, got {exposure_us}")
    check_exposure_us(exposure_us)
    check_gain_db(gain_db, nan_is_default=False)


def requested_gain_db(gain_db, gain_db_set: bool = False) -> float:
    """The gain a message's (gain_db, gain_db_set) asks for, NaN for "the node's / camera's
    gain": NaN, or 0 with gain_db_set false. `ros2 action send_goal` / `ros2 service call` fill
    a field left out with 0 / false, so a goal or pattern without a gain gets the default gain,
    not 0 dB; 0 dB is asked for with gain_db_set true. Any other value is the gain asked for
    (checked with `check_gain_db` where it is used)."""
    value = float(gain_db)
    if math.isnan(value) or (value == 0.0 and not gain_db_set):
        return math.nan
    return value


def gain_db_fields(gain_db: float | None) -> dict:
    """A message's gain fields for a gain in dB (None or NaN: the default gain):
    {'gain_db': ..., 'gain_db_set': ...}, the inverse of `requested_gain_db`."""
    value = math.nan if gain_db is None else float(gain_db)
    return {"gain_db": value, "gain_db_set": not math.isnan(value)}
