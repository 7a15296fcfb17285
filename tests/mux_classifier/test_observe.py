"""The classifier's observing mode without ROS: assembling trigger sequences, recognising the
artifact's patterns, classifying each observed sequence once."""
import threading
import time

import numpy as np
import pytest

from mux_classifier.inference import ImageMatcher, classify_frames, mono16_to_gray
from mux_classifier.observe import (SequenceAssembler, SequenceObserver, TriggerState,
                                    artifact_image_count, observed_sequence, pattern_matches)

STAMP0 = 1_700_000_000_000_000_000


def _states(patterns, request_id=5, stamp0=STAMP0, seq0=100, source='lightstage'):
    k = patterns.shape[1]
    return [TriggerState(request_id, i, k, np.asarray(patterns[:, i], np.float32),
                         stamp0 + i * 25_000_000, seq0 + i, stamp0 + i * 25_000_000 + 1000, source)
            for i in range(k)]


@pytest.fixture(scope='module')
def frames(stage_capture, stage_artifact):
    """mono16 frames of one sample under the artifact's 8 patterns, from the sim camera."""
    from lightstage_physics.capture_format import load_capture
    from lightstage_camera.sim_camera import SimCamera
    camera = SimCamera(load_capture(stage_capture), sample='orange-real/s0/p01', noise='sigma3', seed=1)
    return [camera.capture(stage_artifact.led_patterns[:, i], 22500, 17.5) for i in range(8)]


def test_pattern_matching_tolerates_pwm_rounding_and_on_off_rigs():
    expected = np.zeros(32)
    expected[[1, 4]] = [1.0, 0.7]
    assert pattern_matches(expected.astype(np.float32), expected)
    assert pattern_matches(expected + 0.001, expected)
    on_off = np.zeros(32)
    on_off[[1, 4]] = 1.0  # an on/off rig lights every LED driven above 0.5, and reports 1
    assert pattern_matches(on_off, expected)
    assert not pattern_matches(on_off, np.roll(expected, 1))
    assert not pattern_matches(expected + 0.1, expected)
    assert not pattern_matches(np.zeros(31), np.zeros(32))


def test_only_the_artifacts_first_k_patterns_with_a_classifier_for_k_count(stage_artifact):
    P = stage_artifact.led_patterns
    assert stage_artifact.n_images == [4, 8]
    assert artifact_image_count([P[:, i] for i in range(4)], stage_artifact) == 4
    assert artifact_image_count([P[:, i] for i in range(8)], stage_artifact) == 8
    assert artifact_image_count([P[:, i] for i in range(6)], stage_artifact) == 0  # no classifier for 6
    assert artifact_image_count([P[:, i] for i in range(4, 8)], stage_artifact) == 0  # not the first
    assert artifact_image_count([P[:, i] for i in (1, 0, 2, 3)], stage_artifact) == 0  # order matters


def test_assembler_completes_requests_in_any_order_and_keeps_sources_apart(stage_artifact):
    P = stage_artifact.led_patterns[:, :4]
    a = SequenceAssembler(max_pending=2)
    states = _states(P)
    other = _states(P, source='second_stage')
    assert a.add(states[2]) is None and a.add(other[0]) is None
    assert a.add(states[0]) is None and a.add(states[3]) is None
    done = a.add(states[1])
    assert [s.index for s in done] == [0, 1, 2, 3]
    seq = observed_sequence(done, stage_artifact)
    assert seq.n_images == 4 and seq.sequences == [100, 101, 102, 103]
    assert seq.stamps_ns == [s.stamp_ns for s in states]
    # a repeated index starts the request over (a restarted driver reuses ids)
    assert a.add(states[0]) is None and a.add(states[0]) is None
    for s in states[1:3]:
        assert a.add(s) is None
    assert a.add(states[3]) is not None
    # bounded: old incomplete requests are dropped
    for r in range(10, 14):
        a.add(_states(P, request_id=r)[0])
    assert a.dropped >= 2


def _observer(stage_artifact, published, errors, busy=None, timeout_s=5.0):
    matcher = ImageMatcher(64)
    return SequenceObserver(lambda: stage_artifact, matcher, published.append, stage_busy=busy,
                            timeout_s=lambda: timeout_s, on_error=errors.append), matcher


def test_observed_sequence_is_classified_as_the_service_path_would(stage_artifact, frames):
    published, errors = [], []
    observer, matcher = _observer(stage_artifact, published, errors)
    try:
        states = _states(stage_artifact.led_patterns[:, :8])
        for s, f in list(zip(states, frames))[:3]:  # some images come before their triggers
            matcher.add(s.stamp_ns, f)
        for s in reversed(states):
            observer.on_trigger(s)
        for s, f in list(zip(states, frames))[3:]:
            matcher.add(s.stamp_ns, f)
        assert observer.join_idle(10.0)
    finally:
        observer.close()
    assert not errors
    (r,) = published
    expected, _ = classify_frames(stage_artifact, frames)
    assert r.label == expected.label and r.images_used == 8
    np.testing.assert_allclose(r.scores, expected.scores, rtol=1e-6)
    assert r.sequences == list(range(100, 108)) and r.first_stamp_ns == STAMP0
    assert r.label.startswith('orange')


def test_own_sequences_other_patterns_and_missing_images(stage_artifact, frames):
    published, errors = [], []
    busy = threading.Lock()
    observer, matcher = _observer(stage_artifact, published, errors, busy=busy, timeout_s=0.2)
    try:
        # 1. a sequence the node lit through its service: registered while the stage is busy,
        #    so the observer, which waits for the stage, always knows it
        own = _states(stage_artifact.led_patterns[:, :4], request_id=1)
        with busy:
            for s in own:
                observer.on_trigger(s)
            observer.mark_own(own[0].stamp_ns)
        # 2. somebody else's patterns
        for s in _states(np.ones((32, 4), np.float32) * 0.0, request_id=2, stamp0=STAMP0 + 10**9):
            observer.on_trigger(s)
        # 3. the artifact's patterns, but images 2 and 4 never come: image 3 came after
        #    image 2's turn (the stream is in order), nothing after image 4
        lost = _states(stage_artifact.led_patterns[:, :4], request_id=3, stamp0=STAMP0 + 2 * 10**9,
                       seq0=200)
        for s in lost:
            observer.on_trigger(s)
        for s, f in zip(lost, frames):
            if s.index not in (1, 3):
                matcher.add(s.stamp_ns, f)
        assert observer.join_idle(10.0)
    finally:
        observer.close()
    assert published == []
    stats = observer.stats
    assert (stats.own_skipped, stats.not_artifact, stats.failed, stats.sequences_seen) == (1, 1, 1, 3)
    (error,) = errors
    assert error.startswith('observed request 3 (4 images) not classified: image 2 (trigger '
                            'sequence 201, stamp 1700000002.025000000) did not come: a later image '
                            '(stamp 1700000002.050000000) arrived first'), error
    assert 'not waiting for the other 1 image(s) still on their way' in error
    assert len(matcher) == 2  # the failed sequence's images are no longer kept for it


def test_a_lost_image_fails_only_its_own_sequence_and_at_once(stage_artifact, frames):
    """A stream of 12 sequences of 8 images, in order, with one image missing mid-stream
    (as a recording that missed it replays): the one sequence fails as soon as the next image
    arrives -- the time limit (600 s) cannot be what ends its wait -- and the 11 others are
    classified, though the observer's worker is held up and the image buffer is small."""
    published, errors = [], []
    held_up = threading.Lock()  # the worker waits for it before each sequence
    matcher = ImageMatcher(8)   # one sequence's worth of unclaimed images
    observer = SequenceObserver(lambda: stage_artifact, matcher, published.append,
                                stage_busy=held_up, timeout_s=lambda: 600.0,
                                on_error=errors.append)
    n, k, dropped = 12, 8, (5, 3)  # sequence 5's image 4 is lost
    start = time.monotonic()
    try:
        with held_up:  # the whole stream arrives before the worker handles anything
            for r in range(n):
                states = _states(stage_artifact.led_patterns[:, :k], request_id=r,
                                 stamp0=STAMP0 + r * 10**9, seq0=100 + r * k)
                for s, f in zip(states, frames):
                    observer.on_trigger(s)
                    if (r, s.index) != dropped:
                        matcher.add(s.stamp_ns, f)
        assert observer.join_idle(60.0)
    finally:
        observer.close()
    assert time.monotonic() - start < 60.0  # far from the 600 s limit (join_idle's bound)
    assert observer.stats.classified == n - 1 and observer.stats.failed == 1
    assert [r.sequences[0] for r in published] == [100 + r * k for r in range(n) if r != 5]
    (error,) = errors
    assert error.startswith('observed request 5 (8 images) not classified: image 4 (trigger '
                            'sequence 143, '), error
    assert 'did not come: a later image' in error and 'did not arrive' not in error
    assert matcher.evicted == 0 and len(matcher) == k - 1  # only the failed one's are left


def test_a_replayed_bag_played_again_is_not_mistaken_for_lost_images(stage_artifact, frames):
    """Played from its start again, a bag repeats older stamps: the images that arrived in
    the first pass (later stamps) say nothing about the second pass's, which are waited for."""
    published, errors = [], []
    observer, matcher = _observer(stage_artifact, published, errors, timeout_s=600.0)
    try:
        for _ in range(2):
            states = _states(stage_artifact.led_patterns[:, :4], request_id=7)
            later = _states(stage_artifact.led_patterns[:, :4], request_id=8,
                            stamp0=STAMP0 + 10**9, seq0=300)
            for batch in (states, later):
                arrival = time.time_ns()
                for s in batch:  # the trigger states arrive (now), then the images
                    observer.on_trigger(TriggerState(s.request_id, s.index, s.count,
                                                     s.intensities, s.stamp_ns, s.sequence,
                                                     arrival, s.source))
                time.sleep(0.05)  # the images come a little later, as from a camera
                for s, f in zip(batch, frames):
                    matcher.add(s.stamp_ns, f)
            assert observer.join_idle(60.0)
    finally:
        observer.close()
    assert not errors
    assert len(published) == 4


def test_a_graded_boards_rounded_drive_matches_its_request_and_not_the_next_step():
    from mux_classifier.observe import pattern_matches
    requested = np.linspace(0.0, 1.0, 32)
    requested[3] = 0.3
    applied = (np.round(requested * 255) / 255).astype(np.float32)  # what a pwm_bits 8 board lights
    assert np.abs(applied - requested).max() > 1 / 512  # 0.3 -> 77/255 is 0.00196 off
    assert pattern_matches(applied, requested)
    one_step_up = applied.copy()
    one_step_up[5] += np.float32(1 / 255)
    assert not pattern_matches(one_step_up, applied)


def _with_confidence(artifact, stop, temperature):
    from dataclasses import replace

    from mux_classifier.confidence import Confidence
    return replace(artifact, confidence=Confidence(
        temperatures={k: temperature for k in artifact.n_images}, stop_probability=stop))


@pytest.mark.parametrize('temperature, used', [(1e-3, 4), (1e3, 8)], ids=['sure', 'unsure'])
def test_an_anytime_sequence_lit_column_by_column_is_decided_as_the_service_decided_it(
        stage_artifact, frames, temperature, used):
    """The anytime calls light one column per request; the observer joins a request that
    continues its driver's last one and stops where the artifact's rule stops."""
    artifact = _with_confidence(stage_artifact, 0.9, temperature)
    published, errors = [], []
    observer, matcher = _observer(artifact, published, errors)
    try:
        first = _states(artifact.led_patterns[:, :4], request_id=5)
        for s, f in zip(first, frames[:4]):
            matcher.add(s.stamp_ns, f)
            observer.on_trigger(s)
        if used == 8:  # the live call went on: its next request lights columns 4..7
            second = _states(artifact.led_patterns[:, 4:8], request_id=6,
                             stamp0=STAMP0 + 10**9, seq0=104)
            for s, f in zip(second, frames[4:]):
                matcher.add(s.stamp_ns, f)
                observer.on_trigger(s)
        assert observer.join_idle(10.0)
    finally:
        observer.close()
    assert not errors
    (r,) = published
    expected = artifact.decide(np.stack([mono16_to_gray(f) for f in frames[:used]]),
                               final=used == 8)
    assert r.images_used == used and r.images_budget == 8 and r.calibrated
    assert r.label == expected.label and r.decision == expected.decision
    assert r.sequences == list(range(100, 100 + used)) and r.first_stamp_ns == STAMP0


def test_an_anytime_sequence_its_caller_cut_short_is_decided_on_the_images_it_has(
        stage_artifact, frames):
    """A call with max_images 4 stops after one column whatever the rule says; no next
    request comes, and the observer decides it on its 4 images (unsure) after waiting."""
    artifact = _with_confidence(stage_artifact, 0.9, 1e3)
    published, errors = [], []
    observer, matcher = _observer(artifact, published, errors)
    try:
        for s, f in zip(_states(artifact.led_patterns[:, :4]), frames[:4]):
            matcher.add(s.stamp_ns, f)
            observer.on_trigger(s)
        assert observer.join_idle(10.0)
    finally:
        observer.close()
    assert not errors
    (r,) = published
    assert (r.images_used, r.images_budget, r.decision) == (4, 4, 'unsure')
