"""Calibration at training time: temperatures and the anytime target from held-out answers."""
import numpy as np
import pytest
from mux_classifier.artifact import TrainedArtifact
from mux_classifier.confidence import expected_calibration_error, softmax
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


def test_train_says_what_it_calibrated_in_words(stage_calibrated_artifact_path):
    from mux_trainer.cli import confidence_text
    art = TrainedArtifact.load(stage_calibrated_artifact_path)
    text = confidence_text(art.confidence.to_dict())
    assert text.startswith('calibrated probabilities; anytime: stops after the first pattern')
    assert f'{100 * art.confidence.stop_probability:.3g} %' in text
    assert 'held-out answers (physical samples)' in text and 'calibration error' in text


def test_pooled_calibration_error_is_that_of_all_answers_together():
    from mux_trainer.calibration import pooled_calibration_error, reliability_bins
    rng = np.random.default_rng(3)
    p = rng.dirichlet(np.full(4, 0.6), size=400)
    y = rng.integers(0, 4, 400)
    parts = [reliability_bins(p[i:i + 100], y[i:i + 100]) for i in range(0, 400, 100)]
    assert pooled_calibration_error(parts) == pytest.approx(expected_calibration_error(p, y))
    # not the mean of the parts' errors: each part's bins are noisier
    assert pooled_calibration_error(parts) < np.mean(
        [pooled_calibration_error([b]) for b in parts])


def test_calibration_error_floor_is_what_a_calibrated_classifier_measures():
    from mux_trainer.calibration import calibration_error_floor, reliability_bins
    rng = np.random.default_rng(5)
    p = rng.dirichlet(np.full(5, 0.5), size=300)
    top, label = p.max(axis=1), p.argmax(axis=1)
    measured = []
    for _ in range(300):  # answers right with exactly their probability
        right = rng.random(top.size) < top
        measured.append(expected_calibration_error(p, np.where(right, label, (label + 1) % 5)))
    floor = calibration_error_floor([reliability_bins(p, label)])
    assert floor == pytest.approx(np.mean(measured), rel=0.15)
    # four times the answers: about half the floor
    assert calibration_error_floor([reliability_bins(np.tile(p, (4, 1)), np.tile(label, 4))]) \
        == pytest.approx(floor / 2, rel=0.05)


def test_one_image_count_accepts_at_nine_in_ten():
    from mux_trainer.calibration import ACCEPT_PROBABILITY
    p = np.array([[0.95, 0.05], [0.6, 0.4], [0.2, 0.8]])
    target, measured = choose_stop([p], [1], np.array([0, 1, 1]))
    assert target == ACCEPT_PROBABILITY == 0.9
    assert measured['anytime_mean_images'] == measured['full_images'] == 1
    assert measured['anytime_accuracy'] == measured['full_accuracy'] == 2 / 3


def test_answers_of_one_image_count_are_their_own_anytime_answers():
    from mux_trainer.calibration import answers_figures
    p = np.array([[0.95, 0.05], [0.6, 0.4], [0.2, 0.8], [0.7, 0.3]])
    y = np.array([0, 1, 1, 0])
    a = answers_figures([p], np.array([8]), y, 0.9)
    assert a['anytime_accuracy'] == a['full_accuracy'] == 0.75
    assert a['anytime_mean_images'] == a['budget_images'] == 8
    assert a['accepted_share'] == 0.25 and a['accepted_accuracy'] == 1.0  # only 0.95 >= 0.9
    assert a['full_calibration_error'] == pytest.approx(expected_calibration_error(p, y))
    assert [c['accuracy'] for c in a['coverage_curve']][-1] == 0.75


def test_answers_all_right_are_not_made_certain():
    # 200 held-out answers, every one right: the log loss alone wants T -> 0 (probability 1)
    rng = np.random.default_rng(2)
    scores = rng.normal(0, 1, (200, 3))
    labels = scores.argmax(axis=1)
    t = fit_temperature(scores, labels)
    top = softmax(scores, t).max(axis=1)
    assert top.mean() == pytest.approx(201 / 202, abs=1e-6)   # Laplace: (n + 1) / (n + 2)
    assert top.min() < 0.999
