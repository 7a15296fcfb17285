"""Calibration at training time: temperatures and the anytime target from held-out answers."""
import numpy as np
import pytest
from mux_classifier.artifact import TrainedArtifact
from mux_classifier.confidence import softmax
from mux_trainer.calibration import STOP_TARGETS, choose_stop, fit_temperature


def test_the_fitted_temperature_is_the_one_the_answers_were_drawn_with():
    rng = np.random.default_rng(0)
    scores = rng.normal(0, 3, (4000, 3))
    for true_t in (0.5, 2.0):
        p = softmax(scores, true_t)
        labels = np.array([rng.choice(3, p=row) for row in p])
        assert fit_temperature(scores, labels) == pytest.approx(true_t, rel=0.15)


def test_the_stop_target_is_the_cheapest_that_keeps_the_full_counts_accuracy():
    # 3 answers sure and right at step 0; 1 unsure at step 0 and right only at step 1
    step0 = np.array([[0.97, 0.03], [0.96, 0.04], [0.04, 0.96], [0.55, 0.45]])
    step1 = np.array([[0.99, 0.01], [0.99, 0.01], [0.01, 0.99], [0.2, 0.8]])
    labels = np.array([0, 0, 1, 1])
    target, measured = choose_stop([step0, step1], [4, 8], labels, tolerance=0.0)
    assert target in STOP_TARGETS and 0.55 < target <= 0.96
    assert measured['anytime_accuracy'] == measured['full_accuracy'] == 1.0
    assert measured['anytime_mean_images'] == 5.0   # three stop at 4, one takes 8
    # a tolerance of 25 points lets the unsure one stop early, wrong
    target, measured = choose_stop([step0, step1], [4, 8], labels, tolerance=0.25)
    assert target <= 0.5 and measured['anytime_mean_images'] == 4.0


def test_a_calibrated_stage_artifact_carries_its_rule_and_what_it_measured(
        stage_calibrated_artifact_path):
    art = TrainedArtifact.load(stage_calibrated_artifact_path)
    c = art.confidence
    assert art.calibrated and c.counts == [4, 8] and art.anytime_steps() == [4, 8]
    est = c.estimate
    assert est['held_out'] == 'physical samples'   # 2 samples per class
    assert est['anytime_accuracy'] >= est['full_accuracy'] - c.tolerance - 1e-9
    assert 4 <= est['anytime_mean_images'] <= 8 and est['answers'] > 0
    assert 0 <= est['calibration_error_full'] <= 1
