"""The page's API requests as plain data: each body checked field by field (a `RequestError`
naming the field and what to send instead, HTTP 4xx), the action goals they make, and the
words a running job's progress is said in. The core of `lightstage web`'s API (no rclpy);
`web_state` holds what the page shows.
"""
from __future__ import annotations

import math
from pathlib import Path

class RequestError(ValueError):
    """A request to the page's API that cannot be served as asked (HTTP 4xx); the message
    names the field and what to send instead."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


# --------------------------------------------------------------------------- requests


def _field(body: dict, name: str, kind, default):
    value = body.get(name, default)
    if kind is bool:
        if not isinstance(value, bool):
            raise RequestError(f'{name} must be true or false; got {value!r}')
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0 or value >= 2**32:
            raise RequestError(f'{name} must be a whole number from 0 to {2**32 - 1}; got {value!r}')
        return value
    if kind is float:
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise RequestError(f'{name} must be a finite number (or null: the node\'s setting); '
                               f'got {value!r}')
        return float(value)
    if not isinstance(value, str):
        raise RequestError(f'{name} must be a string; got {value!r}')
    return value.strip()


def _known(body, fields: set[str], what: str) -> dict:
    if not isinstance(body, dict):
        raise RequestError(f'{what}: the body must be a JSON object; got {type(body).__name__}')
    unknown = sorted(set(body) - fields)
    if unknown:
        raise RequestError(f'{what}: unknown field(s) {", ".join(unknown)}; known: '
                           f'{", ".join(sorted(fields))}')
    return body


def classify_request(body) -> dict:
    """{max_images, timeout_s} (both optional) -> the Classify request's fields."""
    from mux_classifier.classify_request import request_max_images, request_timeout_s
    body = _known(body, {'max_images', 'timeout_s'}, 'classify')
    try:
        return {'max_images': request_max_images(body.get('max_images', 0)),
                'timeout_s': request_timeout_s(body.get('timeout_s', 0.0))}
    except ValueError as exc:
        raise RequestError(str(exc)) from None


def _absolute(path: str) -> str:
    """Paths go to the node, which may run in another directory."""
    return str(Path(path).expanduser().absolute()) if path else ''


def capture_goal(body) -> dict:
    """{output_dir, target 'label/sample/pose', exposure_us, gain_db, frames_averaged,
    overwrite} -> CaptureModel goal fields."""
    from lightstage_bringup.acquisition_cli import parse_target
    body = _known(body, {'output_dir', 'target', 'exposure_us', 'gain_db', 'frames_averaged',
                         'overwrite'}, 'capture')
    output_dir = _field(body, 'output_dir', str, '')
    if not output_dir:
        raise RequestError('output_dir: give the capture folder to write into')
    try:
        label, sample, pose, sim_sample = parse_target(_field(body, 'target', str, ''))
    except ValueError as exc:
        raise RequestError(str(exc)) from None
    if sim_sample:
        raise RequestError('target: =SIM_SAMPLE is for the command line; put the sample on the '
                           'stage first (lightstage capture TARGET=SIM_SAMPLE does both)')
    return {'output_dir': _absolute(output_dir), 'label': label, 'sample': sample, 'pose': pose,
            'exposure_us': _field(body, 'exposure_us', int, 0),
            'gain_db': _field(body, 'gain_db', float, None),
            'frames_averaged': _field(body, 'frames_averaged', int, 0),
            'overwrite': _field(body, 'overwrite', bool, False)}


def calibrate_goal(body) -> dict:
    """{output_path, plot_path, exposure_us, gain_db, frames_per_level, levels, overwrite}
    -> CalibrateNoise goal fields."""
    body = _known(body, {'output_path', 'plot_path', 'exposure_us', 'gain_db',
                         'frames_per_level', 'levels', 'overwrite'}, 'calibrate')
    return {'output_path': _absolute(_field(body, 'output_path', str, '')),
            'plot_path': _absolute(_field(body, 'plot_path', str, '')),
            'exposure_us': _field(body, 'exposure_us', int, 0),
            'gain_db': _field(body, 'gain_db', float, None),
            'frames_per_level': _field(body, 'frames_per_level', int, 0),
            'levels': _field(body, 'levels', int, 0),
            'overwrite': _field(body, 'overwrite', bool, False)}


def capture_progress(images_done: int, images_total: int, current_led: str, stage: str) -> tuple[str, float]:
    """CaptureModel feedback -> (text, fraction done)."""
    if stage == 'capturing':
        return f'{images_done}/{images_total} LED images ({current_led})', \
            images_done / images_total if images_total else 0.0
    return stage, (1.0 if stage == 'writing' else 0.0)


def calibrate_progress(level: int, levels: int, frames_done: int, frames_total: int,
                       leds_lit: int, stage: str) -> tuple[str, float]:
    """CalibrateNoise feedback -> (text, fraction done)."""
    if stage == 'capturing' and levels and frames_total:
        done = (level - 1 + frames_done / frames_total) / levels
        return f'level {level}/{levels} ({leds_lit} LEDs): {frames_done}/{frames_total} frames', done
    return stage, (1.0 if stage in ('fitting', 'writing') else 0.0)
