"""Calibrated probabilities, the anytime rule and the decision of one answer (no ROS)."""
import json
import math

import numpy as np
import pytest
from mux_classifier.artifact import ArtifactError, TrainedArtifact
from mux_classifier.artifact_format import CONFIDENCE_SINCE
from mux_classifier.confidence import (ACCEPTED, UNSURE, Confidence, ConfidenceError,
                                       anytime_outcomes, check_target_probability,
                                       expected_calibration_error, softmax)
from mux_classifier.inference import ImageMatcher, classify_on_stage

from helpers.artifact_checks import rewrite_artifact


def test_softmax_rows_sum_to_one_and_a_higher_temperature_flattens_them():
    scores = np.array([[2.0, 0.0, -1.0], [1000.0, 0.0, 0.0]])
    p = softmax(scores)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    assert np.isfinite(p).all() and p[1, 0] == pytest.approx(1.0)
    assert softmax(scores, 4.0)[0, 0] < p[0, 0] < softmax(scores, 0.5)[0, 0]


def test_the_calibration_error_is_zero_when_confidence_matches_accuracy_and_large_when_not():
    # 80 % confident, right 4 times in 5
    p = np.tile([0.8, 0.2], (10, 1))
    y = np.array([0, 0, 0, 0, 1] * 2)
    assert expected_calibration_error(p, y) == pytest.approx(0.0)
    # 99 % confident, right half the time
    p = np.tile([0.99, 0.01], (10, 1))
    assert expected_calibration_error(p, np.array([0, 1] * 5)) == pytest.approx(0.49)


def test_the_anytime_rule_stops_each_answer_at_the_first_step_that_reaches_the_target():
    steps = [np.array([[0.95, 0.05], [0.6, 0.4], [0.5, 0.5]]),
             np.array([[0.2, 0.8], [0.9, 0.1], [0.45, 0.55]])]
    stop, predicted, reached = anytime_outcomes(steps, 0.9)
    assert stop.tolist() == [0, 1, 1]          # the first is sure at once
    assert predicted.tolist() == [0, 0, 1]     # not revised by the later step
    assert reached.tolist() == [True, True, False]


@pytest.mark.parametrize('bad', [{}, {'x': 1.0}, {'4': 0.0}, {'4': math.nan}, {'0': 1.0},
                                 {'four': 1.0}, {'4': True}])
def test_malformed_temperatures_are_refused_naming_them(bad):
    with pytest.raises(ConfidenceError):
        Confidence(temperatures=bad, stop_probability=0.9)


@pytest.mark.parametrize('value, expected', [(0, None), (0.0, None), (0.9, 0.9), (1.0, 1.0)])
def test_a_target_of_zero_means_the_trained_rule(value, expected):
    assert check_target_probability(value) == expected


@pytest.mark.parametrize('bad', [-0.1, 1.5, math.nan, math.inf, 'x', True])
def test_a_target_outside_zero_to_one_is_refused(bad):
    with pytest.raises(ConfidenceError, match='target_probability must be a number in 0 .. 1'):
        check_target_probability(bad)


def _calibrated(artifact, stop=0.9, temperatures=None):
    from dataclasses import replace
    temps = temperatures or {k: 1.0 for k in artifact.n_images}
    return replace(artifact, confidence=Confidence(temperatures=temps, stop_probability=stop,
                                                   estimate={'answers': 10}))


def test_a_calibrated_artifact_is_written_as_format_7_and_reads_back(stage_artifact, tmp_path):
    assert not stage_artifact.calibrated and stage_artifact.anytime_steps() == [8]
    art = _calibrated(stage_artifact, temperatures={4: 0.5, 8: 2.0})
    art.save(tmp_path / 'c.npz')
    with np.load(tmp_path / 'c.npz', allow_pickle=False) as npz:
        header = json.loads(npz['header'].tobytes().decode())
    assert header['format_version'] == CONFIDENCE_SINCE == 7
    back = TrainedArtifact.load(tmp_path / 'c.npz')
    assert back.calibrated and back.confidence == art.confidence
    assert back.anytime_steps() == [4, 8] and back.anytime_steps(7) == [4]
    assert 'calibrated, anytime stop at 90 %' in back.describe()
    # an uncalibrated artifact keeps its older format: releases before 7 still read it
    stage_artifact.save(tmp_path / 'u.npz')
    with np.load(tmp_path / 'u.npz', allow_pickle=False) as npz:
        assert json.loads(npz['header'].tobytes().decode())['format_version'] < 7


@pytest.mark.parametrize('change, match', [
    (lambda h: h.update(confidence=[1]), "'confidence' must be an object"),
    (lambda h: h['confidence'].update(stop_probability=2), 'stop_probability must be'),
    (lambda h: h['confidence']['temperatures'].update({'12': 1.0}), 'image counts \\[12\\]'),
    (lambda h: h['confidence'].update(extra=1), 'unknown keys'),
])
def test_a_malformed_calibration_in_a_file_is_refused_with_the_reason(stage_artifact, tmp_path,
                                                                      change, match):
    _calibrated(stage_artifact).save(tmp_path / 'c.npz')
    rewrite_artifact(tmp_path / 'c.npz', tmp_path / 'd.npz', change_header=change)
    with pytest.raises(ArtifactError, match=match):
        TrainedArtifact.load(tmp_path / 'd.npz')


def _stack(modelset, artifact, name, k):
    from lightstage_physics.render import render_led_patterns
    i = modelset.sample_names.index(name)
    return np.clip(render_led_patterns(modelset.subset([i]), artifact.led_patterns[:, :k])[0],
                   0, 1023)


def test_decide_accepts_a_sure_answer_stops_early_and_calls_an_unsure_one_so(stage_artifact,
                                                                          stage_modelset):
    images = _stack(stage_modelset, stage_artifact, 'orange-real/s1/p01', 4)
    scores = stage_artifact.predict_stack(images).scores
    sure = _calibrated(stage_artifact, stop=0.6, temperatures={4: 1e-3, 8: 1e-3})
    d = sure.decide(images)
    assert d.decision == ACCEPTED and d.stop and d.n_images == 4
    assert d.probabilities.sum() == pytest.approx(1.0) and d.label == sure.class_names[
        int(np.argmax(scores))] and math.isnan(d.novelty)
    flat = _calibrated(stage_artifact, stop=0.9, temperatures={4: 1e3, 8: 1e3})
    d = flat.decide(images)
    assert d.decision == UNSURE and not d.stop      # goes on to the next column
    assert flat.decide(images, final=True).stop     # the budget is spent
    # target 1: every image, the decision by the trained target
    d = sure.decide(images, target_probability=1.0)
    assert not d.stop and d.decision == ACCEPTED
    # uncalibrated: no probabilities, stops only at the end
    d = stage_artifact.decide(images)
    assert d.probabilities.size == 0 and d.decision == ACCEPTED and not d.stop


def test_classify_on_stage_asks_one_column_at_a_time_and_stops_when_sure(stage_artifact,
                                                                        stage_modelset):
    from lightstage_camera.sim_camera import SimCamera
    camera = SimCamera(stage_modelset, sample='orange-real/s1/p01', noise='none')
    stamp = iter(range(1_700_000_000_000_000_000, 1_800_000_000_000_000_000, 1_000_000))

    def run(artifact, target=None):
        matcher, lit = ImageMatcher(), []

        def apply(plan, timeout_s):
            lit.append(plan.n_images)
            stamps = [next(stamp) for _ in range(plan.n_images)]
            for s, p in zip(stamps, plan.led_patterns.T):
                matcher.add(s, camera.capture(p, plan.exposure_us, plan.gain_db))
            return stamps, list(range(len(stamps)))
        return classify_on_stage(artifact, apply, matcher, timeout_s=5.0,
                                 target_probability=target), lit

    sure = _calibrated(stage_artifact, stop=0.6, temperatures={4: 1e-3, 8: 1e-3})
    result, lit = run(sure)
    assert lit == [4] and result.images_used == 4 and result.images_budget == 8
    assert result.decision == ACCEPTED and result.calibrated and result.probabilities.size == 4
    result, lit = run(sure, target=1.0)       # fixed count
    assert lit == [4, 4] and result.images_used == 8
    flat = _calibrated(stage_artifact, stop=0.9, temperatures={4: 1e3, 8: 1e3})
    result, lit = run(flat)
    assert lit == [4, 4] and result.decision == UNSURE and result.images_used == 8
    result, lit = run(stage_artifact)         # uncalibrated: one sequence, as ever
    assert lit == [8] and not result.calibrated and result.probabilities.size == 0


def test_the_classifier_says_its_inner_estimate_and_how_it_was_held_out(stage_artifact):
    from dataclasses import replace
    art = replace(stage_artifact, provenance={**stage_artifact.provenance, 'inner_estimate': {
        'accuracy': 0.747, 'held_out': 'physical samples', 'n_images': 2}})
    assert 'inner estimate 74.7 % on held-out physical samples' in art.describe()
