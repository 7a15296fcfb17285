"""What the operator's page shows, as plain data: the core of `lightstage web` (no rclpy).

The ROS side (`web_node`) hands every message it receives to a `PageState` as plain Python
values; the web server (`web_app`) reads `snapshot()` (JSON) and the images (`png()`). One
lock guards it, since ROS callbacks and the web server run on different threads; every
change bumps `version` and calls `on_change` (the server then pushes the new state).

Images are matched to the LEDs lit for them by trigger stamp (the camera stamps each image
with its trigger's stamp; the driver publishes that stamp and the trigger's sequence number
on /illumination), and a classification's images by the sequence numbers its result names.
Stamps go out as strings (nanoseconds since 1970 do not fit a JavaScript number exactly).
Gray values are MSB-aligned 16-bit; the page shows each image stretched so that its 99.5th
percentile is white, and says how bright its brightest pixel was of the camera's full scale.

Health is never shown older than it is: a /diagnostics status not updated for
`DIAGNOSTIC_STALE_S` is shown STALE (diagnostic_aggregator's rule: no update within its
timeout, 5 s by default); a status of a node that has left the graph is shown STALE at once; an
OK status of a lifecycle node that is not active is shown WARN "not armed". `tick()` (called
every second) makes the page see the time pass.
"""
from __future__ import annotations

import io
import math
import threading
import time
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from lightstage_physics.rig import CHANNELS, N_LEDS, Rig

# the API's requests (`web_requests`) are part of this module's interface
from .web_requests import (RequestError, calibrate_goal, calibrate_progress,  # noqa: F401
                           capture_goal, capture_progress, classify_request)

THUMBNAIL_PX = 240      # images kept with a classification: at most this many pixels a side
LIVE_MAX_PX = 800       # the live image: at most this many pixels a side
DIAGNOSTIC_LEVELS = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}
DIAGNOSTIC_STALE_S = 5.0   # diagnostic_aggregator's default timeout
SATURATED = 0.98           # a brightest pixel at this fraction of full scale: likely clipped


# --------------------------------------------------------------------------- images


def display_image(pixels: np.ndarray, max_px: int) -> tuple[np.ndarray, float]:
    """A mono16 image (H, W) -> (8-bit image at most `max_px` a side, stretched so its 99.5th
    percentile is white; the brightest pixel as a fraction of the 16-bit full scale)."""
    image = np.asarray(pixels)
    peak = float(image.max()) / 65535.0 if image.size else 0.0
    step = max(1, math.ceil(max(image.shape) / max_px))
    if step > 1:  # block mean: the shown image keeps the noise level a person expects
        h, w = (image.shape[0] // step) * step, (image.shape[1] // step) * step
        image = image[:h, :w].reshape(h // step, step, w // step, step).mean(axis=(1, 3))
    image = image.astype(np.float32)
    white = float(np.percentile(image, 99.5)) if image.size else 0.0
    if white <= 0:
        return np.zeros(image.shape, np.uint8), peak
    return np.clip(image * (255.0 / white), 0, 255).astype(np.uint8), peak


def encode_png(image: np.ndarray) -> bytes:
    from PIL import Image
    out = io.BytesIO()
    Image.fromarray(image, mode='L').save(out, format='PNG', compress_level=1)
    return out.getvalue()


@dataclass
class Frame:
    """One camera image as the page keeps it. The image to show is made when first asked
    for (a camera can send frames faster than a page looks at them): from `pixels` (mono16 as
    received) at most `max_px` a side, or given ready (`image`, 8-bit)."""
    stamp_ns: int
    width: int
    height: int
    peak: float                # brightest pixel / 16-bit full scale
    received: float            # wall time [s]
    pixels: np.ndarray | None = None
    image: np.ndarray | None = None
    max_px: int = LIVE_MAX_PX
    _png: bytes | None = None

    def png(self) -> bytes:
        if self._png is None:
            if self.image is None:
                self.image = display_image(self.pixels, self.max_px)[0]
            self._png = encode_png(self.image)
        return self._png


@dataclass
class Illumination:
    sequence: int
    stamp_ns: int
    request_id: int
    index: int
    count: int
    intensities: list[float]
    exposure_us: int
    gain_db: float

    def as_dict(self) -> dict:
        return {'sequence': self.sequence, 'stamp_ns': str(self.stamp_ns), 'request_id': self.request_id,
                'index': self.index, 'count': self.count,
                'intensities': [round(float(v), 4) for v in self.intensities],
                'exposure_us': self.exposure_us,
                'gain_db': None if math.isnan(self.gain_db) else round(self.gain_db, 3)}


# --------------------------------------------------------------------------- the state


@dataclass
class Job:
    """A capture or noise calibration started from the page."""
    id: int
    kind: str                  # 'capture' | 'calibrate'
    goal: dict
    state: str = 'starting'    # starting, running, cancelling, succeeded, failed, canceled
    progress: str = ''
    fraction: float = 0.0
    message: str = ''
    result: dict = field(default_factory=dict)
    started: float = field(default_factory=time.time)
    ended: float | None = None
    goal_id: str = ''          # the action goal's UUID (hex) once accepted
    known: bool = True         # False: a goal found running on the node, not started here

    @property
    def running(self) -> bool:
        return self.state in ('starting', 'running', 'cancelling')

    def as_dict(self) -> dict:
        return {'id': self.id, 'kind': self.kind, 'goal': self.goal, 'state': self.state,
                'progress': self.progress, 'fraction': round(self.fraction, 4),
                'message': self.message, 'result': self.result, 'started': self.started,
                'ended': self.ended, 'goal_id': self.goal_id, 'known': self.known}


class PageState:
    """The page's picture of the graph; every method is safe from any thread."""

    def __init__(self, history_size: int = 30, image_buffer: int = 40, events_size: int = 50,
                 rig: Rig | None = None, on_change: Callable[[], None] | None = None,
                 stale_s: float = DIAGNOSTIC_STALE_S, clock: Callable[[], float] = time.monotonic):
        self._lock = threading.Lock()
        self.stale_s = stale_s
        self._clock = clock
        self._nodes: dict[str, dict] = {}   # node name -> {'state', 'lifecycle'}
        self._defaults: dict = {}           # the acquisition node's settings, by parameter
        self._shown_health: tuple = ()      # the health last shown, to notice when it ages
        self.on_change = on_change
        self.version = 0
        self.history_version = 0   # the history alone changes less often than the rest
        self.rig = rig or Rig.paper_default()
        self._frames: OrderedDict[int, Frame] = OrderedDict()       # by stamp
        self._illumination: OrderedDict[int, Illumination] = OrderedDict()  # by sequence
        self._stamp_to_sequence: dict[int, int] = {}
        self._image_buffer = image_buffer
        self._live: Frame | None = None
        self._history: deque[dict] = deque(maxlen=history_size)
        self._history_frames: dict[int, Frame] = {}  # stamp -> thumbnail, for history entries
        # history entries whose trigger's illumination / image has not come yet
        self._awaiting_illumination: dict[int, list[dict]] = {}   # by sequence
        self._awaiting_image: dict[int, list[dict]] = {}          # by stamp
        self._events: deque[dict] = deque(maxlen=events_size)
        self._diagnostics: dict[str, dict] = {}
        self._jobs: deque[Job] = deque(maxlen=10)
        self._next_id = 1
        self._classify_running = False
        self.connected = {'ros': False}

    # ------------------------------------------------------------------ plumbing
    def _changed(self) -> None:
        """Under the lock: a new version; the callback runs after the lock is released."""
        self.version += 1

    def _notify(self) -> None:
        if self.on_change is not None:
            self.on_change()

    def _new_id(self) -> int:
        n = self._next_id
        self._next_id += 1
        return n

    def event(self, level: str, source: str, text: str) -> None:
        """Something the person should see (a lost frame, a failed classify, a driver fault)."""
        with self._lock:
            self._event(level, source, text)
        self._notify()

    def _event(self, level: str, source: str, text: str) -> None:
        self._events.appendleft({'id': self._new_id(), 'time': time.time(), 'level': level,
                                 'source': source, 'text': text})
        self._changed()

    # ------------------------------------------------------------------ inputs from the graph
    def on_illumination(self, ill: Illumination) -> None:
        with self._lock:
            self._illumination[ill.sequence] = ill
            self._stamp_to_sequence[ill.stamp_ns] = ill.sequence
            while len(self._illumination) > 4 * self._image_buffer:
                old = self._illumination.popitem(last=False)[1]
                self._stamp_to_sequence.pop(old.stamp_ns, None)
                self._awaiting_illumination.pop(old.sequence, None)
                self._awaiting_image.pop(old.stamp_ns, None)
            if ill.sequence in self._awaiting_illumination:
                self._attach_illumination(ill)
            self._changed()
        self._notify()

    def on_image(self, stamp_ns: int, pixels: np.ndarray) -> None:
        """A mono16 image (H, W) stamped with its trigger."""
        peak = float(pixels.max()) / 65535.0 if pixels.size else 0.0
        frame = Frame(stamp_ns, int(pixels.shape[1]), int(pixels.shape[0]), peak, time.time(), pixels)
        with self._lock:
            self._frames[stamp_ns] = frame
            while len(self._frames) > self._image_buffer:
                self._frames.popitem(last=False)
            for entry in self._awaiting_image.pop(stamp_ns, []):
                self._attach_image(entry, frame)
            self._live = frame
            self._changed()
        self._notify()

    def on_frame_lost(self, sequence: int, stamp_ns: int, reason: str) -> None:
        self.event('error', 'camera', f'frame of trigger {sequence} lost: {reason}')

    def on_result(self, result: dict) -> None:
        """A ClassificationResult (`label`, `class_names`, `scores`, `images_used`,
        `sequences`, `acquisition_ms`, `compute_ms`, `stamp_ns`; from a calibrated classifier
        also `probabilities`, `decision`, `novelty`, `images_budget`) -> the history, with the
        images and illumination of its sequences (those still on their way are added when
        they come: each topic has a reader of its own)."""
        with self._lock:
            images = [{'sequence': int(seq), 'illumination': None, 'image': None}
                      for seq in result.get('sequences', [])]
            for entry in images:
                self._awaiting_illumination.setdefault(entry['sequence'], []).append(entry)
                ill = self._illumination.get(entry['sequence'])
                if ill is not None:
                    self._attach_illumination(ill)
            item = {'id': self._new_id(), 'time': time.time(), 'success': True, 'message': '',
                    **{k: result[k] for k in ('label', 'class_names', 'scores', 'images_used',
                                              'acquisition_ms', 'compute_ms')},
                    'probabilities': list(result.get('probabilities') or []),
                    'decision': result.get('decision') or 'accepted',
                    'novelty': result.get('novelty'),
                    'images_budget': int(result.get('images_budget') or result['images_used']),
                    'calibrated': bool(result.get('calibrated')),
                    'stamp_ns': str(result['stamp_ns']), 'images': images}
            self._add_history(item)
            for awaiting in (self._awaiting_illumination, self._awaiting_image):
                while len(awaiting) > 4 * self._image_buffer:  # what never came stays missing
                    awaiting.pop(next(iter(awaiting)))
        self._notify()

    def _attach_illumination(self, ill: Illumination) -> None:
        """Under the lock: history entries waiting for this trigger get its LEDs (and image)."""
        for entry in self._awaiting_illumination.pop(ill.sequence, []):
            entry['illumination'] = ill.as_dict()
            self.history_version += 1
            frame = self._frames.get(ill.stamp_ns)
            if frame is not None:
                self._attach_image(entry, frame)
            else:
                self._awaiting_image.setdefault(ill.stamp_ns, []).append(entry)
        self._changed()

    def _attach_image(self, entry: dict, frame: Frame) -> None:
        thumb = self._thumbnail(frame)
        self._history_frames[thumb.stamp_ns] = thumb
        entry['image'] = {'stamp_ns': str(thumb.stamp_ns), 'width': frame.width,
                          'height': frame.height, 'peak': round(frame.peak, 4),
                          'saturated': frame.peak >= SATURATED}
        self.history_version += 1
        self._changed()

    def _add_history(self, item: dict) -> None:
        if len(self._history) == self._history.maxlen:
            self._forget(self._history[-1])
        self._history.appendleft(item)
        self.history_version += 1
        self._changed()

    def _thumbnail(self, frame: Frame) -> Frame:
        """The small 8-bit copy a history entry keeps (not the camera's full frame)."""
        image = frame.image if frame.pixels is None else display_image(frame.pixels, THUMBNAIL_PX)[0]
        return Frame(frame.stamp_ns, frame.width, frame.height, frame.peak, frame.received,
                     image=image, max_px=THUMBNAIL_PX)

    def _forget(self, item: dict) -> None:
        """A history entry falls off the end: its images go unless a newer entry has them."""
        kept = {i['image']['stamp_ns'] for h in list(self._history)[:-1] for i in h.get('images', [])
                if i.get('image')}
        for i in item.get('images', []):
            if i.get('image') and i['image']['stamp_ns'] not in kept:
                self._history_frames.pop(int(i['image']['stamp_ns']), None)

    def on_classify_answer(self, answer: dict) -> None:
        """The Classify service's answer to a call from the page: a failure goes into the
        history and the events (a success arrives with its images on the result topic)."""
        with self._lock:
            if not answer['success']:
                item = {'id': self._new_id(), 'time': time.time(), 'success': False,
                        'message': answer['message'], 'label': '', 'class_names': [],
                        'scores': [], 'images_used': 0, 'acquisition_ms': 0.0,
                        'compute_ms': 0.0, 'stamp_ns': '0', 'images': []}
                self._add_history(item)
                self._event('error', 'classifier', f'classification failed: {answer["message"]}')
            self._changed()
        self._notify()

    def on_diagnostics(self, statuses: list[dict]) -> None:
        """DiagnosticStatus entries (`name`, `level`, `message`, `hardware_id`, `values`); a
        status that turns ERROR (or recovers from it) is also an event."""
        with self._lock:
            for status in statuses:
                name = status['name']
                before = self._diagnostics.get(name)
                level = DIAGNOSTIC_LEVELS.get(int(status['level']), str(status['level']))
                self._diagnostics[name] = {**status, 'level': level, 'received': time.time(),
                                           'seen': self._clock()}
                if level == 'ERROR' and (before is None or before['level'] != 'ERROR'):
                    self._event('error', name, f'ERROR: {status["message"]}')
                elif before is not None and before['level'] == 'ERROR' and level != 'ERROR':
                    self._event('info', name, f'{level} again: {status["message"]}')
            self._changed()
        self._notify()

    def set_node(self, name: str, node_state: str, lifecycle: bool = False) -> None:
        """A node of the graph: 'running' (a plain node in the graph), a lifecycle state
        ('active', 'inactive', 'unconfigured', 'finalized'), or 'stopped' (gone from the
        graph; 'not started' if it never was in it). Changes are events."""
        with self._lock:
            before = self._nodes.get(name)
            if before is None and node_state == 'stopped':
                node_state = 'not started'
            elif before is not None and before['state'] == 'not started' and node_state == 'stopped':
                node_state = 'not started'
            if before is not None and before['state'] == node_state and before['lifecycle'] == lifecycle:
                return
            self._nodes[name] = {'state': node_state, 'lifecycle': lifecycle}
            if before is not None and before['state'] != node_state:
                if node_state == 'stopped':
                    self._event('error', name, f'the {name} node stopped: it left the graph')
                elif lifecycle and node_state != 'active':
                    self._event('warning', name, f'the {name} node is {node_state}: not armed')
                elif before['state'] in ('stopped', 'not started') or node_state == 'active':
                    self._event('info', name, f'the {name} node is {node_state}')
            self._changed()
        self._notify()

    def _shown_diagnostic(self, d: dict, now: float) -> dict:
        """Under the lock: a status as the page shows it (aged, its node's state applied)."""
        node = self._nodes.get(d['name'].split(':', 1)[0])
        last = f'last report {d["level"]}: {d["message"]}'
        shown = {k: v for k, v in d.items() if k != 'seen'}
        shown['reported_level'] = d['level']
        shown['age_s'] = round(now - d['seen'], 1)
        if node is not None and node['state'] in ('stopped', 'not started'):
            shown.update(level='STALE', stale=True,
                         message=f'the {d["name"].split(":", 1)[0]} node is not running ({last})')
        elif now - d['seen'] > self.stale_s:
            shown.update(level='STALE', stale=True,
                         message=f'no update for more than {self.stale_s:g} s ({last})')
        elif node is not None and node['lifecycle'] and node['state'] != 'active' and d['level'] == 'OK':
            shown.update(level='WARN', stale=False,
                         message=f'not armed: the node is {node["state"]} ({d["message"]})')
        else:
            shown['stale'] = False
        return shown

    def tick(self) -> None:
        """Time passed: a status that aged past `stale_s` is shown so (the page is told)."""
        with self._lock:
            now = self._clock()
            health = tuple((d['name'], self._shown_diagnostic(d, now)['level'])
                           for d in self._diagnostics.values())
            if health == self._shown_health:
                return
            self._shown_health = health
            self._changed()
        self._notify()

    def set_defaults(self, values: dict) -> None:
        """The acquisition node's settings that a goal field of 0 (or no gain) stands for."""
        with self._lock:
            self._defaults = dict(values)
            self._changed()
        self._notify()

    def set_connected(self, what: str, up: bool) -> None:
        with self._lock:
            if self.connected.get(what) != up:
                self.connected[what] = up
                self._changed()
        self._notify()

    # ------------------------------------------------------------------ classify calls
    def begin_classify(self) -> None:
        """One classify from the page at a time (the stage does one anyway)."""
        with self._lock:
            if self._classify_running:
                raise RequestError('a classification started from this page is still running; '
                                   'wait for its answer', status=409)
            self._classify_running = True
            self._changed()
        self._notify()

    def end_classify(self) -> None:
        with self._lock:
            self._classify_running = False
            self._changed()
        self._notify()

    # ------------------------------------------------------------------ jobs
    def start_job(self, kind: str, goal: dict) -> Job:
        with self._lock:
            running = next((j for j in self._jobs if j.running), None)
            if running is not None:
                raise RequestError(f'a {running.kind} is running (job {running.id}); wait for it '
                                   'or cancel it first: the stage does one at a time', status=409)
            job = Job(self._new_id(), kind, goal)
            self._jobs.appendleft(job)
            self._changed()
        self._notify()
        return job

    def running_job(self) -> Job | None:
        with self._lock:
            return next((j for j in self._jobs if j.running), None)

    def job_plot_path(self, job_id: int) -> str | None:
        """The plot file a succeeded calibration job wrote (None if none)."""
        with self._lock:
            job = next((j for j in self._jobs if j.id == job_id), None)
            if job is None or job.kind != 'calibrate' or job.state != 'succeeded':
                return None
            return job.result.get('plot_path') or job.goal.get('plot_path') or None

    def on_active_goals(self, kind: str, goal_ids: list[str]) -> None:
        """The goals the action server of `kind` says are active (its status topic). One this
        page did not start (started elsewhere, or before this page's server restarted) is
        shown as a job whose progress is not known here; it can be cancelled. Such a job
        ends when the server no longer lists it."""
        with self._lock:
            if any(j.kind == kind and j.state == 'starting' for j in self._jobs):
                return   # a goal of this page's, not yet answered: it is not someone else's
            ours = {j.goal_id for j in self._jobs if j.goal_id}
            for j in self._jobs:
                if not j.known and j.running and j.kind == kind and j.goal_id not in goal_ids:
                    self._set_job(j, state='ended', message='it is no longer running on the node; '
                                  'its result is not known here (see the node\'s log and the output)')
            for goal_id in goal_ids:
                if goal_id not in ours:
                    job = Job(self._new_id(), kind, {}, state='running', goal_id=goal_id, known=False,
                              message=f'a {kind} this page did not start (another client, or this '
                                      'page\'s server restarted while it ran) is running on the '
                                      'node; its progress is not known here; Cancel stops it')
                    self._jobs.appendleft(job)
                    self._event('warning', kind, job.message)
                    self._changed()
        self._notify()

    def update_job(self, job: Job, **changes) -> None:
        with self._lock:
            self._set_job(job, **changes)
        self._notify()

    def _set_job(self, job: Job, **changes) -> None:
        for key, value in changes.items():
            setattr(job, key, value)
        if not job.running and job.ended is None:
            job.ended = time.time()
            if job.state != 'succeeded':
                self._event('error' if job.state == 'failed' else 'warning', job.kind,
                            f'{job.kind} {job.state}: {job.message}')
        self._changed()

    # ------------------------------------------------------------------ outputs
    def snapshot(self, history_since: int | None = None) -> dict:
        """Everything the page shows; the history is left out if it is the one of
        `history_version` `history_since` (a page that has it keeps it)."""
        with self._lock:
            now = self._clock()
            live = None
            if self._live is not None:
                seq = self._stamp_to_sequence.get(self._live.stamp_ns)
                ill = self._illumination.get(seq) if seq is not None else None
                live = {'stamp_ns': str(self._live.stamp_ns), 'width': self._live.width,
                        'height': self._live.height, 'peak': round(self._live.peak, 4),
                        'saturated': self._live.peak >= SATURATED,
                        'received': self._live.received,
                        'illumination': ill.as_dict() if ill else None}
            snap = {'version': self.version, 'history_version': self.history_version,
                    'connected': dict(self.connected), 'stage': self.stage_layout(), 'live': live,
                    'classify_running': self._classify_running, 'events': list(self._events),
                    'diagnostics': [self._shown_diagnostic(d, now) for d in
                                    sorted(self._diagnostics.values(), key=lambda d: d['name'])],
                    'nodes': {k: dict(v) for k, v in self._nodes.items()},
                    'defaults': dict(self._defaults),
                    'stale_s': self.stale_s, 'saturated_at': SATURATED,
                    'jobs': [j.as_dict() for j in self._jobs]}
            if history_since != self.history_version:
                snap['history'] = list(self._history)
            return snap

    def stage_layout(self) -> dict:
        """Where the sites are (mm, seen from the camera) and the LED channels, to draw."""
        return {'sites': [{'name': s.name, 'x_mm': s.x_mm, 'y_mm': s.y_mm} for s in self.rig.sites],
                'channels': list(CHANNELS), 'n_leds': N_LEDS}

    def png(self, which: str) -> bytes:
        """'live' or a stamp (ns) of an image the page has -> PNG; RequestError(404) if none."""
        with self._lock:
            if which == 'live':
                frame = self._live
            else:
                try:
                    stamp = int(which)
                except ValueError:
                    raise RequestError(f'image {which!r}: expected "live" or an image stamp in '
                                       'ns (a whole number)') from None
                frame = self._history_frames.get(stamp) or self._frames.get(stamp)
        if frame is None:
            raise RequestError(f'no image {which}: the camera has sent none yet' if which == 'live'
                               else f'no image with stamp {which} is kept (the page keeps the '
                                    'images of its classification history)', status=404)
        return frame.png()
