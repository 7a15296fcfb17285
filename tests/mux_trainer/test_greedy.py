import numpy as np
import pytest
from mux_classifier.artifact import ArtifactError, TrainedArtifact

from mux_trainer.candidate_patterns import pattern_code
from mux_trainer.greedy import GreedyPatternSelector, could_still_win
from mux_trainer.reference import reference_candidate_scores
from mux_trainer.search_params import Refinement, SplitScoring


def brute_force_greedy(data, n_columns, n_repeats, seed, classifier='linear_svm'):
    """The paper's loop written plainly: every pattern in natural binary order, each
    scored by the straightforward reference (per-image render, skimage HOG, a classifier
    fitted per split: LinearSVC as in the paper, or ridge); returns the chosen columns and
    each column's {code: score}."""
    n = data.n_sites
    patterns = np.array([[(code >> i) & 1 for i in range(n)]
                         for code in range(1, 2 ** n - 1)], np.float32).T
    columns = np.zeros((n, 0), np.float32)
    scores_by_column = []
    for _ in range(n_columns):
        acc = reference_candidate_scores(data, 'per_colour', columns if columns.shape[1] else None,
                                         patterns, seed=seed, n_repeats=n_repeats,
                                         classifier=classifier).mean(axis=1)
        scores_by_column.append({pattern_code(p): a for p, a in zip(patterns.T, acc)})
        columns = np.hstack([columns, patterns[:, [int(np.argmax(acc))]]])
    return columns, scores_by_column


def test_greedy_selects_the_brute_force_patterns(tiny4_data):
    """Default search (ridge screen, exact SVM on the screen's top 16, here all 14) against
    the paper's loop with one LinearSVC per split: the same columns, the same SVM scores."""
    sel = GreedyPatternSelector(n_patterns=3, seed=11,
                                scoring=SplitScoring(n_repeats=20)).fit(tiny4_data)
    ref_cols, ref_scores = brute_force_greedy(tiny4_data, 3, 20, 11)
    for j, record in enumerate(sel.history_):
        assert len(record['refined']) == 14
        svm = {pattern_code(record['candidates'][:, i]): s
               for i, s in zip(record['refined'], record['refined_scores'])}
        assert svm.keys() == ref_scores[j].keys()
        assert all(svm[c] == ref_scores[j][c] for c in svm)
        best = max(ref_scores[j].values())
        assert record['accuracy'] == best
        assert [c for c, s in ref_scores[j].items() if s == best] == \
            [pattern_code(record['pattern'])], 'a unique winner per column, the same'
    np.testing.assert_array_equal(sel.patterns_, ref_cols)
    assert list(sel.accuracy_by_images_) == [1, 2, 3]


def test_ridge_screen_alone_selects_the_brute_force_ridge_patterns(tiny4_data):
    sel = GreedyPatternSelector(n_patterns=3, seed=11, scoring=SplitScoring(n_repeats=20),
                                refinement=Refinement(top=0)).fit(tiny4_data)
    ref_cols, ref_scores = brute_force_greedy(tiny4_data, 3, 20, 11, classifier='ridge')
    for j, record in enumerate(sel.history_):
        assert 'refined' not in record
        fast = {pattern_code(p): s for p, s in zip(record['candidates'].T, record['scores'])}
        assert fast.keys() == ref_scores[j].keys()  # all 14 patterns with 1..3 of 4 sites
        assert all(fast[c] == ref_scores[j][c] for c in fast)
        best = max(ref_scores[j].values())
        winners = [c for c, s in ref_scores[j].items() if s == best]
        assert len(winners) == 1, 'the tiny problem should have a unique winner per column'
    np.testing.assert_array_equal(sel.patterns_, ref_cols)
    assert list(sel.accuracy_by_images_) == [1, 2, 3]


def test_early_termination_stops_at_the_first_non_improving_column(tiny_data):
    full = GreedyPatternSelector(n_patterns=4, seed=0,
                                 scoring=SplitScoring(n_repeats=16)).fit(tiny_data)
    acc = [full.accuracy_by_images_[k] for k in (1, 2, 3, 4)]
    best = np.maximum.accumulate(acc)
    expected_improved = [True] + [acc[i] > best[i - 1] for i in range(1, 4)]
    np.testing.assert_array_equal(full.improved_, expected_improved)
    early = GreedyPatternSelector(n_patterns=None, max_patterns=4, seed=0,
                                  scoring=SplitScoring(n_repeats=16)).fit(tiny_data)
    stop = expected_improved.index(False) if False in expected_improved else 4
    assert early.patterns_.shape[1] == stop
    np.testing.assert_array_equal(early.patterns_, full.patterns_[:, :stop])
    assert len(early.history_) == min(stop + 1, 4)  # the rejected column is recorded
    if stop < 4:
        assert early.history_[-1]['kept'] is False
    assert set(early.classifiers_) == set(range(1, stop + 1))


def test_early_termination_when_one_column_is_perfect():
    from helpers.trainer import make_search_data
    easy = make_search_data(signal=200.0, noise_a=0.0, noise_b=0.0)
    sel = GreedyPatternSelector(max_patterns=5, seed=0,
                                scoring=SplitScoring(n_repeats=10)).fit(easy)
    assert sel.accuracy_by_images_[1] == 1.0
    assert sel.patterns_.shape[1] == 1 and len(sel.history_) == 2


def test_same_seed_same_result_other_seed_other_noise(tiny_data):
    a = GreedyPatternSelector(n_patterns=2, seed=3,
                              scoring=SplitScoring(n_repeats=10)).fit(tiny_data)
    b = GreedyPatternSelector(n_patterns=2, seed=3,
                              scoring=SplitScoring(n_repeats=10)).fit(tiny_data)
    c = GreedyPatternSelector(n_patterns=2, seed=4,
                              scoring=SplitScoring(n_repeats=10)).fit(tiny_data)
    np.testing.assert_array_equal(a.patterns_, b.patterns_)
    np.testing.assert_array_equal(a.history_[1]['scores'], b.history_[1]['scores'])
    assert not np.array_equal(a.history_[0]['scores'], c.history_[0]['scores'])


def test_joint_mode_beam_search_over_led_additions(tiny_data):
    sel = GreedyPatternSelector(mode='joint', n_patterns=2, seed=0, beam_width=2,
                                scoring=SplitScoring(n_repeats=10),
                                refinement=Refinement(top=0)).fit(tiny_data)
    assert sel.patterns_.shape == (32, 2)
    first = sel.history_[0]
    singles = first['candidates'][:, :32]
    np.testing.assert_array_equal(singles, np.eye(32, dtype=np.float32))
    ref = reference_candidate_scores(tiny_data, 'joint', None, singles, seed=0, n_repeats=10,
                                     classifier='ridge').mean(axis=1)
    np.testing.assert_array_equal(first['scores'][:32], ref)
    # the column is the best pattern seen, and it is at least as good as the best single LED
    assert first['accuracy'] == first['scores'].max() >= ref.max()
    lit = int(sel.patterns_[:, 0].sum())
    # beam 2: step t tries at most 2 * (33 - t) patterns
    assert first['candidates'].shape[1] <= 32 + sum(2 * (32 - t) for t in range(1, lit + 1))
    # the joint mode learns something on this data: the informative LEDs are red of
    # site 0 / 2 and NIR of site 1
    assert sel.accuracy_by_images_[2] > 0.6


def test_saved_classifier_reloads_and_predicts_identically(tiny_data, tmp_path):
    sel = GreedyPatternSelector(n_patterns=2, seed=0,
                                scoring=SplitScoring(n_repeats=8)).fit(tiny_data)
    art = sel.to_artifact()
    # the noise setting is the estimator's, recorded at fit from the data it rendered with
    assert sel.noise_['name'] == tiny_data.noise_name
    assert art.noise == sel.noise_
    path = tmp_path / 'greedy.npz'
    art.save(path)
    loaded = TrainedArtifact.load(path)
    assert loaded.n_images == [4, 8] and loaded.mode == 'per_colour'
    np.testing.assert_array_equal(loaded.site_patterns, sel.patterns_)
    from mux_trainer.evaluation import render
    from mux_trainer.rendering import add_noise
    imgs = add_noise(tiny_data, render(tiny_data, 'per_colour', sel.patterns_), None)
    stacks = imgs.transpose(1, 0, 2).reshape(tiny_data.n_samples, 8, 24, 24)
    np.testing.assert_array_equal(art.decision_function(stacks), loaded.decision_function(stacks))
    np.testing.assert_array_equal(loaded.predict(stacks[:, :4]), art.predict(stacks[:, :4]))
    # the artifact's classifier is the selector's
    X = sel.evaluator_.features(sel.patterns_)
    names = np.asarray(tiny_data.class_names)
    np.testing.assert_array_equal(
        names[sel.classifiers_[2].predict_features(X)],
        loaded.classifier(8).predict_features(X))
    with pytest.raises(ArtifactError, match='images'):
        loaded.predict(stacks[:, :3])
    path.write_bytes(b'not a zip')
    with pytest.raises(ArtifactError, match='not an .npz'):
        TrainedArtifact.load(path)


def test_bad_parameters_fail_clearly(tiny_data):
    with pytest.raises(ValueError, match='unknown mode'):
        GreedyPatternSelector(mode='diagonal').fit(tiny_data)
    with pytest.raises(ValueError, match='at least one pattern column'):
        GreedyPatternSelector(n_patterns=0).fit(tiny_data)


def test_refinement_races_down_the_screens_order_and_picks_the_svm_best(tiny_data):
    sel = GreedyPatternSelector(n_patterns=2, seed=2, scoring=SplitScoring(n_repeats=12),
                                refinement=Refinement(top=5, max=40)).fit(tiny_data)
    ridge_only = GreedyPatternSelector(n_patterns=1, seed=2, scoring=SplitScoring(n_repeats=12),
                                       refinement=Refinement(top=0)).fit(tiny_data)
    svm = GreedyPatternSelector(n_patterns=1, seed=2, scoring=SplitScoring(
        n_repeats=12, classifier='squared_hinge')).fit(tiny_data)
    exact = svm.history_[0]['scores']
    first = sel.history_[0]
    scores = first['scores']
    # the screen is the ridge search itself
    np.testing.assert_array_equal(scores, ridge_only.history_[0]['scores'])
    # refined: a prefix of the screen's order, at least the first 5, grown 8 at a time
    order = np.argsort(-scores, kind='stable')
    k = len(first['refined'])
    np.testing.assert_array_equal(first['refined'], order[:k])
    assert k == 5 or (k - 5) % 8 == 0 or k == scores.size
    np.testing.assert_array_equal(first['refined_scores'], exact[first['refined']])
    # it stopped because no other candidate could still win, or at the cap
    if k < min(40, scores.size):
        assert not could_still_win(scores[order[:k]], first['refined_scores'], scores[order[k]],
                                   sel.refinement.slack)
    assert first['best'] == first['refined'][np.argmax(first['refined_scores'])]
    assert first['accuracy'] == sel.accuracy_by_images_[1] == exact[first['best']]
    assert 'refined' not in svm.history_[0]  # nothing to refine with the SVM as the screen
    with pytest.raises(ValueError, match='refine_top'):
        GreedyPatternSelector(refinement=Refinement(top=-1)).fit(tiny_data)


def test_could_still_win_judges_by_how_far_the_svm_rose_above_the_screen():
    screen = np.array([0.90, 0.89, 0.88])
    svm = np.array([0.85, 0.88, 0.86])      # rises -0.05, -0.01, -0.02; best 0.88
    assert could_still_win(screen, svm, 0.89, slack=0.0)        # 0.89 - 0.01 >= 0.88
    assert not could_still_win(screen, svm, 0.885, slack=0.0)   # 0.875 < 0.88
    assert could_still_win(screen, svm, 0.885, slack=1.0)       # + std of the rises


def test_joint_mode_refines_among_every_pattern_the_beam_evaluated(tiny_data):
    common = dict(mode='joint', n_patterns=1, scoring=SplitScoring(n_repeats=6), seed=0,
                  max_lit_leds=3)
    screen = GreedyPatternSelector(**common,
                                   refinement=Refinement(top=0)).fit(tiny_data).history_[0]
    sel = GreedyPatternSelector(**common, refinement=Refinement(top=4)).fit(tiny_data)
    record = sel.history_[0]
    # ridge drives the beam, so the same patterns were evaluated with the same scores
    np.testing.assert_array_equal(record['candidates'], screen['candidates'])
    np.testing.assert_array_equal(record['scores'], screen['scores'])
    order = np.argsort(-screen['scores'], kind='stable')
    assert len(record['refined']) >= 4
    np.testing.assert_array_equal(record['refined'], order[:len(record['refined'])])
    assert record['best'] in record['refined']
    assert record['accuracy'] == record['refined_scores'].max() == sel.accuracy_by_images_[1]
    np.testing.assert_array_equal(sel.patterns_[:, 0], record['candidates'][:, record['best']])


def test_small_search_selects_the_columns_recorded_before_the_compiled_kernels():
    # recorded with the pure-numpy HOG, numpy noise and the LU-solved exact SVM (commit
    # bdde634): the compiled HOG kernel, the fused noise and the Cholesky Newton solves
    # change no screen score, no SVM score and so no column
    from helpers.trainer import make_search_data
    data = make_search_data(noise_b=3000.0)
    sel = GreedyPatternSelector(n_patterns=3, seed=0, scoring=SplitScoring(n_repeats=40)).fit(data)
    columns = [''.join(str(int(v)) for v in col) for col in sel.patterns_.T]
    assert columns == ['01011111', '01001011', '11011101']
    assert sel.accuracy_by_images_ == pytest.approx({1: 0.44375, 2: 0.440625, 3: 0.271875},
                                                    rel=0, abs=1e-12)
    assert [len(h['refined']) for h in sel.history_] == [16, 16, 16]
    assert [h['scores'].sum() for h in sel.history_] == pytest.approx(
        [68.571875, 73.359375, 47.946875], rel=1e-12)


def test_the_count_rule_decides_the_kept_column_count_from_the_same_search(tiny4_data):
    """'one_se' keeps the fewest columns within one standard error of the best mean split
    accuracy; 'max' the best mean. Both from the chosen columns' own split accuracies."""
    from mux_trainer.column_count import split_standard_error
    sel = GreedyPatternSelector(n_patterns=3, seed=11, count_rule='one_se',
                                scoring=SplitScoring(n_repeats=20)).fit(tiny4_data)
    acc = sel.accuracy_by_images_
    assert sorted(sel.split_accuracy_by_images_) == [1, 2, 3]
    for k, splits in sel.split_accuracy_by_images_.items():
        assert splits.shape == (20,) and np.mean(splits) == pytest.approx(acc[k])
    best = max(acc, key=lambda k: (acc[k], -k))
    se = split_standard_error(sel.split_accuracy_by_images_[best], sel.scoring.test_fraction)
    expected = min(k for k in acc if acc[k] >= acc[best] - se)
    assert sel.best_n_patterns_ == expected <= best
    assert sel.set_params(count_rule='max')._best_count() == best
