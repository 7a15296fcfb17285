"""Classifying trigger sequences the classifier only watches (live, or replayed from a bag).

The driver publishes one IlluminationState per trigger: ``request_id``, ``index_in_request``,
``count_in_request``, the LEDs that were lit and the trigger stamp. `SequenceAssembler`
groups them per request; a complete request whose patterns are the artifact's first k
(k one of the image counts it has a classifier for) is an `ObservedSequence`.
`classify_observed` collects its images by stamp (`ImageMatcher`, as the service path does)
and classifies them exactly as `inference.classify_on_stage` would have. `SequenceObserver`
runs that on a worker thread, skipping the sequences its own node lit through the Classify
service (those are classified there already).

A calibrated artifact's anytime calls light one pattern column per request: a request that
lights the artifact's patterns j..k right after one of the same driver that ended at image j
continues that sequence. The observer decides after each request with the artifact's own
rule (`TrainedArtifact.decide`, the trained target) and publishes once it stops, so a replay
gives the labels and image counts the live calls gave (calls that asked for another
``target_probability`` are decided with the trained one). A sequence the rule would go on
with but whose driver lights something else next, or nothing for `CONTINUATION_S`, was cut
short by its caller (``max_images``): it is decided on the images it has.

One lost image fails its own sequence only, and at once: a sequence's images are claimed in
the matcher as soon as its trigger states are complete (however far behind the worker is,
they are not evicted), and the wait for a missing image ends as soon as a later image has
arrived (the camera's stream is reliable and in trigger order), not after the timeout, so
the sequences behind it lose nothing.

Nothing here imports rclpy; the classifier node maps /illumination onto `TriggerState`.
"""
from __future__ import annotations

import queue
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from lightstage_graph.errors import StageError

from .artifact import TrainedArtifact
from .inference import Classification, ImageMatcher, classify_collected

# IlluminationState.intensities are the drives the board applied: a graded board (pwm_bits 8)
# rounds each to its 1/255 steps (up to half a step, 1/510, from the requested drive); on/off
# boards report 0/1 for what was lit. Half a step plus float32 slack matches a graded drive to
# its request; distinct patterns differ by whole steps.
DEFAULT_TOLERANCE = 0.5 / 255.0 + 1e-6
# How long an anytime sequence the rule would go on with waits for its next request before it
# is decided on the images it has: a live call asks for the next column within milliseconds
# of its decision; a replay at a tenth of the speed still well within this.
CONTINUATION_S = 2.0


@dataclass(frozen=True)
class TriggerState:
    """One IlluminationState, as plain values."""
    request_id: int
    index: int
    count: int
    intensities: np.ndarray
    stamp_ns: int
    sequence: int
    arrival_ns: int
    source: str = ''  # header.frame_id: requests of different drivers never mix


@dataclass
class ObservedSequence:
    """A complete trigger sequence that lit the artifact's first ``n_images`` patterns."""
    request_id: int
    stamps_ns: list
    sequences: list
    n_images: int
    first_arrival_ns: int
    source: str = ''
    first_image: int = 0  # > 0: it continues an anytime sequence that ended at this image


def pattern_matches(observed: np.ndarray, expected: np.ndarray,
                    tolerance: float = DEFAULT_TOLERANCE) -> bool:
    """Whether the LEDs lit at one trigger are the pattern ``expected`` (length 32).

    Equal within ``tolerance``, or -- for an on/off rig, which reports 0/1 for what it lit --
    the same LEDs on as ``expected > 0.5``.
    """
    observed = np.asarray(observed, dtype=np.float64).ravel()
    expected = np.asarray(expected, dtype=np.float64).ravel()
    if observed.shape != expected.shape:
        return False
    if np.all(np.abs(observed - expected) <= tolerance):
        return True
    binary = np.all((observed == 0.0) | (observed == 1.0))
    return bool(binary and np.array_equal(observed > 0.5, expected > 0.5))


def artifact_image_count(patterns: Sequence[np.ndarray], artifact: TrainedArtifact,
                         tolerance: float = DEFAULT_TOLERANCE, first_image: int = 0) -> int:
    """k if ``patterns`` are the artifact's LED patterns ``first_image`` .. k-1 and it has a
    classifier for k images; else 0."""
    k = int(first_image) + len(patterns)
    if k not in artifact.n_images:
        return 0
    expected = artifact.led_patterns
    if all(pattern_matches(p, expected[:, first_image + i], tolerance)
           for i, p in enumerate(patterns)):
        return k
    return 0


class SequenceAssembler:
    """Collects TriggerStates per (source, request_id) until a request is complete.

    States may arrive in any order. A request whose index repeats, or whose count changes,
    starts over (a restarted driver reuses request ids). At most ``max_pending`` incomplete
    requests are kept; older ones are dropped and counted in ``dropped``.
    """

    def __init__(self, max_pending: int = 16):
        self.max_pending = int(max_pending)
        self._pending: OrderedDict[tuple, dict[int, TriggerState]] = OrderedDict()
        self.dropped = 0

    def add(self, state: TriggerState) -> list[TriggerState] | None:
        """The request's states in index order once it is complete, else None."""
        if state.count < 1 or not 0 <= state.index < state.count:
            return None
        key = (state.source, state.request_id)
        group = self._pending.get(key)
        if group is not None:
            first = next(iter(group.values()))
            if state.index in group or first.count != state.count:
                del self._pending[key]
                group = None
        if group is None:
            group = self._pending[key] = {}
        group[state.index] = state
        self._pending.move_to_end(key)
        if len(group) == state.count:
            del self._pending[key]
            return [group[i] for i in range(state.count)]
        while len(self._pending) > self.max_pending:
            self._pending.popitem(last=False)
            self.dropped += 1
        return None


def observed_sequence(states: Sequence[TriggerState], artifact: TrainedArtifact,
                      tolerance: float = DEFAULT_TOLERANCE,
                      continues_at: int = 0) -> ObservedSequence | None:
    """The sequence to classify if ``states`` (a complete request) lit the artifact's first
    k patterns, or (``continues_at`` j > 0: the images its driver's last artifact request
    ended at) its patterns j .. k-1; None for any other request (other patterns, other
    count)."""
    patterns = [s.intensities for s in states]
    first = 0
    k = artifact_image_count(patterns, artifact, tolerance)
    if not k and continues_at > 0 and artifact.calibrated:
        k = artifact_image_count(patterns, artifact, tolerance, first_image=continues_at)
        first = continues_at if k else 0
    if not k:
        return None
    return ObservedSequence(states[0].request_id, [s.stamp_ns for s in states],
                            [s.sequence for s in states], k,
                            min(s.arrival_ns for s in states), states[0].source, first)


def classify_observed(artifact: TrainedArtifact, seq: ObservedSequence, matcher: ImageMatcher,
                      timeout_s: float, bit_depth: int = 10) -> Classification:
    """Collect the sequence's images by trigger stamp and classify them.

    ``acquisition_ms`` runs from the arrival of the sequence's first trigger state to the
    arrival of its last image (on this node's clock; on replay it reflects replay timing).
    """
    # none of its images can have come before its first trigger state: only images since
    # then tell that a missing one was passed over (a bag played again repeats old stamps)
    frames, last_arrival_ns = matcher.collect(seq.stamps_ns, timeout_s, seq.sequences,
                                              since_ns=seq.first_arrival_ns)
    return classify_collected(artifact, frames, bit_depth, list(seq.sequences), seq.stamps_ns[0],
                              max(0.0, (last_arrival_ns - seq.first_arrival_ns) / 1e6))


@dataclass
class _OpenSequence:
    """An anytime sequence the rule has not stopped yet: its images so far."""
    seq: ObservedSequence
    artifact: TrainedArtifact
    frames: list
    sequences: list
    last_arrival_ns: int = 0
    waiting_since: float = 0.0


def _collect(seq: ObservedSequence, matcher: ImageMatcher, timeout_s: float):
    return matcher.collect(seq.stamps_ns, timeout_s, seq.sequences,
                           since_ns=seq.first_arrival_ns)


@dataclass
class ObserverStats:
    sequences_seen: int = 0      # complete requests
    classified: int = 0
    own_skipped: int = 0         # lit by this node's Classify service
    not_artifact: int = 0        # other patterns or counts
    failed: int = 0
    behind: int = 0              # not classified: more than max_pending were waiting
    last_error: str = ''
    errors: list = field(default_factory=list)


class SequenceObserver:
    """Classify every observed sequence of the artifact's patterns, once, on a worker thread.

    - ``artifact()``: the current artifact (None: nothing is classified);
    - ``matcher``: the ImageMatcher the node's image subscription fills;
    - ``publish(Classification)``: called for each classified sequence;
    - ``stage_busy``: the lock the node's Classify service holds while it lights and
      collects a sequence. Before deciding on a sequence the worker waits for it to be free,
      so a sequence the service lit is always registered (`mark_own`) by then and skipped;
    - ``on_error(message)``: a sequence that could not be classified (e.g. missing images).

    At most ``max_pending`` sequences wait for the worker (their images are claimed in the
    matcher meanwhile); one beyond that is not classified, and said so.
    """

    def __init__(self, artifact: Callable[[], TrainedArtifact | None], matcher: ImageMatcher,
                 publish: Callable[[Classification], None], *,
                 stage_busy: threading.Lock | None = None, timeout_s: Callable[[], float] = lambda: 10.0,
                 bit_depth: Callable[[], int] = lambda: 10,
                 on_error: Callable[[str], None] = lambda _m: None,
                 tolerance: float = DEFAULT_TOLERANCE, own_memory: int = 256,
                 max_pending: int = 64):
        self._artifact = artifact
        self.matcher = matcher
        self._publish = publish
        self._stage_busy = stage_busy or threading.Lock()
        self._timeout_s = timeout_s
        self._bit_depth = bit_depth
        self._on_error = on_error
        self.tolerance = float(tolerance)
        self.assembler = SequenceAssembler()
        self.stats = ObserverStats()
        self._own: OrderedDict[int, None] = OrderedDict()
        self._own_memory = int(own_memory)
        self._own_lock = threading.Lock()
        self.max_pending = int(max_pending)
        self._queue: queue.Queue = queue.Queue()
        self._assemble_lock = threading.Lock()
        self._ended_at: dict[str, int] = {}     # per driver: image its last artifact request ended at
        self._open: dict[str, _OpenSequence] = {}  # worker only: anytime sequences not stopped
        self._thread = threading.Thread(target=self._run, name='sequence-observer', daemon=True)
        self._thread.start()

    def mark_own(self, first_stamp_ns: int) -> None:
        """A sequence this node lit itself (by its first trigger stamp): never classify it here."""
        with self._own_lock:
            self._own[int(first_stamp_ns)] = None
            while len(self._own) > self._own_memory:
                self._own.popitem(last=False)

    def _is_own(self, seq: ObservedSequence) -> bool:
        with self._own_lock:
            return seq.stamps_ns[0] in self._own

    def on_trigger(self, state: TriggerState) -> None:
        """Feed one IlluminationState (any thread). A request it completes is recognised here
        at once, and the images of an artifact sequence claimed, before the worker gets to it."""
        with self._assemble_lock:
            states = self.assembler.add(state)
            if states is None:
                return
            self.stats.sequences_seen += 1
            artifact = self._artifact()
            if artifact is None:
                return  # no classifier loaded: nothing to classify
            seq = observed_sequence(states, artifact, self.tolerance,
                                    self._ended_at.get(states[0].source, 0))
            if seq is None:
                self._ended_at.pop(states[0].source, None)
                self.stats.not_artifact += 1
                return
            self._ended_at[seq.source] = seq.n_images
            if self._queue.unfinished_tasks >= self.max_pending:
                self.stats.behind += 1
                self._error(f'observed request {seq.request_id} ({seq.n_images} images) not '
                            f'classified: {self.max_pending} observed sequences are already '
                            'waiting to be classified (this node cannot keep up; give it more CPU)')
                return
            self.matcher.claim(seq.stamps_ns)
            self._queue.put((seq, artifact))

    def close(self, timeout_s: float = 5.0) -> None:
        self._queue.put(None)
        self._thread.join(timeout_s)

    def join_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until every queued sequence is handled and no anytime sequence waits for its
        next request (tests)."""
        deadline = time.monotonic() + timeout_s
        while (self._queue.unfinished_tasks or self._open) and time.monotonic() < deadline:
            time.sleep(0.005)
        return not self._queue.unfinished_tasks and not self._open

    def _run(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=CONTINUATION_S / 4)
            except queue.Empty:
                self._close_waiting(CONTINUATION_S)
                continue
            try:
                if item is None:
                    self._close_waiting(0.0)
                    return
                self._handle(item)
            except Exception as exc:  # noqa: BLE001 - the worker must survive any one sequence
                self.stats.failed += 1
                self._error(f'observed sequence not classified: {type(exc).__name__}: {exc}')
            finally:
                self._queue.task_done()

    def _handle(self, item) -> None:
        seq, artifact = item
        try:
            self._classify(seq, artifact)
        finally:
            self.matcher.release(seq.stamps_ns)

    def _classify(self, seq: ObservedSequence, artifact: TrainedArtifact) -> None:
        # a Classify call in progress may be lighting this very sequence: let it finish (it
        # registers its sequences before it lets go of the stage), then decide
        with self._stage_busy:
            own = self._is_own(seq)
        if own:
            self.stats.own_skipped += 1
            self._open.pop(seq.source, None)
            return
        try:
            if artifact.calibrated:
                result = self._decide(seq, artifact)
                if result is None:
                    return  # the rule goes on: wait for the sequence's next request
            else:
                result = classify_observed(artifact, seq, self.matcher,
                                           float(self._timeout_s()), int(self._bit_depth()))
        except StageError as exc:  # InferenceError or MissingImagesError
            self._open.pop(seq.source, None)
            self.stats.failed += 1
            self._error(f'observed request {seq.request_id} ({seq.n_images} images) not '
                        f'classified: {exc}')
            return
        self.stats.classified += 1
        self._publish(result)

    def _decide(self, seq: ObservedSequence, artifact: TrainedArtifact):
        """One step of an anytime sequence: its images so far decided with the artifact's
        rule; the Classification once it stops, else None (the sequence stays open)."""
        from .inference import InferenceError
        opened = self._open.pop(seq.source, None)
        if seq.first_image:
            if opened is None or len(opened.frames) != seq.first_image:
                raise InferenceError(f'it continues an anytime sequence at image '
                                     f'{seq.first_image} whose start was not observed')
        else:
            if opened is not None:  # its caller stopped it (max_images): decide it as it is
                self._publish_closed(opened)
            opened = _OpenSequence(seq, artifact, [], [])
        frames, opened.last_arrival_ns = _collect(seq, self.matcher, float(self._timeout_s()))
        opened.frames += list(frames)
        opened.sequences += list(seq.sequences)
        result = self._decided(opened, final=seq.n_images >= artifact.anytime_steps()[-1])
        if result is None:
            opened.waiting_since = time.monotonic()
            self._open[seq.source] = opened
        return result

    def _decided(self, opened: _OpenSequence, final: bool):
        """The Classification of an open sequence if the rule stops it (or ``final``)."""
        from .inference import _classification, decide_frames
        artifact = opened.artifact
        start = time.perf_counter()
        decision, stack = decide_frames(artifact, opened.frames, int(self._bit_depth()),
                                        final=final)
        compute_ms = (time.perf_counter() - start) * 1e3
        if not decision.stop:
            return None
        first = opened.seq
        budget = artifact.anytime_steps()[-1] if not final or len(opened.frames) >= \
            artifact.anytime_steps()[-1] else len(opened.frames)
        return _classification(artifact, decision, stack, opened.sequences, first.stamps_ns[0],
                               max(0.0, (opened.last_arrival_ns - first.first_arrival_ns) / 1e6),
                               compute_ms, budget)

    def _publish_closed(self, opened: _OpenSequence) -> None:
        try:
            result = self._decided(opened, final=True)
        except StageError as exc:
            self.stats.failed += 1
            self._error(f'observed request {opened.seq.request_id} not classified: {exc}')
            return
        self.stats.classified += 1
        self._publish(result)

    def _close_waiting(self, after_s: float) -> None:
        """Decide the anytime sequences that waited ``after_s`` for a next request that did
        not come (their caller stopped them)."""
        now = time.monotonic()
        for source, opened in list(self._open.items()):
            if now - opened.waiting_since >= after_s:
                del self._open[source]
                self._publish_closed(opened)

    def _error(self, message: str) -> None:
        self.stats.last_error = message
        self.stats.errors = (self.stats.errors + [message])[-20:]
        self._on_error(message)
