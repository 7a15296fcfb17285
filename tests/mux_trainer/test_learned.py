"""Learned illumination: the differentiable statistics, the training and the numpy model."""
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mux_classifier.intensity_stats import intensity_stats_images_numpy
from mux_classifier.learned_model import LearnedModel
from mux_classifier.ratio_stats import n_ratio_stats, ratio_stats

from helpers.trainer import TINY_HOG

from mux_trainer.holdout import holdout_split
from lightstage_physics.rig import site_to_led_patterns
from lightstage_physics.rig import Rig
from mux_trainer.evaluation import CandidateEvaluator
from mux_trainer.holdout import evaluate_learned_heldout
from mux_trainer.learned import (Descent, Head, LearnedIlluminationClassifier, Starts,
                                 cv_ridge_loss, fit_fixed_light_head, image_stats,
                                 low_side_splits, opposite_low_sides, pose_folds, inner_seeds,
                                 raking_name, raking_sides_start, stack_features,
                                 stack_ratio_stats, stack_stats)
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.rendering import SearchData, clean_led_images, clean_site_images
from mux_trainer.learned.head import learned_data
from mux_trainer.search_params import SplitScoring
from mux_trainer.selection_bias import selection_optimism, split_groups


def disk_data(n_classes=3, n_poses=8, size=24, seed=0):
    """A bright disk anywhere on a dark floor; class k reflects 60 % more under one LED
    (site k, NIR) than the others do; each pose also varies in overall brightness (a
    nuisance every LED sees)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    models, labels, poses = [], [], []
    for k in range(n_classes):
        for p in range(n_poses):
            cy, cx = rng.uniform(7, size - 7, 2)
            disk = ((yy - cy) ** 2 + (xx - cx) ** 2 < 25).astype(np.float32)
            refl = rng.uniform(0.8, 1.2) * rng.uniform(0.9, 1.1, (4, 8)).astype(np.float32)
            refl[3, k] *= 1.6
            models.append(8.0 + 90.0 * refl[:, :, None, None] * disk)
            labels.append(k)
            poses.append(p)
    return SearchData.from_models(np.stack(models), labels, poses,
                                  [f'c{k}' for k in range(n_classes)], dimmer=1.0,
                                  noise_a=0.7, noise_b=66.0, hog_config=TINY_HOG)


def _images(data, k=3, seed=0):
    P = np.random.default_rng(seed).uniform(0, 1, (32, k)).astype(np.float32)
    return clean_led_images(data, P)  # (k, n, pixels)


def test_statistics_equal_the_numpy_reference(tiny_data):
    images = _images(tiny_data)
    k, n, p = images.shape
    # a dark floor around a bright object, as on the stage, so the mask matters
    framed = np.zeros((k * n, 30, 30), np.float32)
    framed[:, 3:27, 3:27] = images.reshape(k * n, 24, 24)
    framed += np.random.default_rng(1).normal(5, 1, framed.shape).astype(np.float32)
    ref = intensity_stats_images_numpy(framed)
    out = np.asarray(jax.jit(lambda x: image_stats(x, (30, 30)))(
        jnp.asarray(framed.reshape(k * n, -1))))
    np.testing.assert_allclose(out, ref, rtol=2e-5, atol=1e-3)


def test_statistics_pass_a_finite_gradient_to_the_levels(tiny_data):
    basis = jnp.asarray(tiny_data.basis[:, :, :8].reshape(32, 8, -1))

    def score(P):
        images = jnp.tensordot(P, basis, axes=([0], [0]))
        return stack_stats(images, tiny_data.image_shape).sum()

    g = np.asarray(jax.grad(score)(jnp.full((32, 2), 0.5)))
    assert np.isfinite(g).all() and np.abs(g).max() > 0


def test_cross_image_statistics_equal_the_numpy_ones_and_pass_a_gradient(tiny_data):
    images = _images(tiny_data, k=3) + np.float32(4.0)
    k, n, p = images.shape
    stacks = images.reshape(k, n, *tiny_data.image_shape).transpose(1, 0, 2, 3)
    out = np.asarray(jax.jit(lambda x: stack_ratio_stats(x, tiny_data.image_shape, 5.0))(
        jnp.asarray(images)))
    np.testing.assert_allclose(out, ratio_stats(stacks, 5.0), rtol=1e-4, atol=1e-5)
    basis = jnp.asarray(tiny_data.basis[:, :, :8].reshape(32, 8, -1))
    g = np.asarray(jax.grad(lambda P: stack_ratio_stats(
        jnp.tensordot(P, basis, axes=([0], [0])), tiny_data.image_shape, 5.0).sum())(
            jnp.asarray(np.random.default_rng(2).uniform(0, 1, (32, 3)), jnp.float32)))
    assert np.isfinite(g).all() and np.abs(g).max() > 0


def test_the_model_can_classify_with_the_cross_image_statistics(tiny_data):
    kwargs = dict(n_images=2, starts=Starts(names=('per_colour',)),
                  descent=Descent(fine_tune='per_colour', max_steps=4, eval_every=2, batch_size=8),
                  scoring=SplitScoring(n_repeats=20), head=Head(renders=2), seed=0)
    model = LearnedIlluminationClassifier(ratio_stats=True, **kwargs).fit(tiny_data)
    m = model.model_
    assert m.ratio_offset == pytest.approx(0.01 * tiny_data.max_level)
    assert m.n_features == 2 * 9 + n_ratio_stats(2) and m.layers[0][0].shape[0] == m.n_features
    # inner scores come from the whole stack's features; they differ from the model without
    plain = LearnedIlluminationClassifier(ratio_stats=False, **kwargs).fit(tiny_data)
    assert set(model.candidate_scores_) == set(plain.candidate_scores_)
    assert model.candidate_scores_ != plain.candidate_scores_
    assert plain.model_.ratio_offset == 0 and plain.model_.n_features == 18
    images = clean_led_images(tiny_data, m.patterns)
    k, n, _ = images.shape
    stacks = images.transpose(1, 0, 2).reshape(n, k, *tiny_data.image_shape)
    np.testing.assert_array_equal(model.predict_images(images), m.predict(stacks))
    np.testing.assert_array_equal(model.predict_features(m.features(stacks), 2), m.predict(stacks))
    with pytest.raises(ValueError, match='cross-image'):
        model.predict_features(np.zeros((3, 18)), 2)
    # one image has no pair: the model is the 9 statistics' (an offset, no extra values)
    one = LearnedIlluminationClassifier(**{**kwargs, 'n_images': 1},
                                        ratio_stats=True).set_params(descent__max_steps=2).fit(tiny_data)
    assert one.model_.n_features == 9


@pytest.fixture(scope='module')
def fitted():
    data = disk_data()
    train_idx, test_idx = holdout_split(data, 0.25, seed=0)
    train, test = data.subset(train_idx), data.subset(test_idx)
    # ridge 0.1: 18 training samples for 18 statistics need more than the default's 0.01
    model = LearnedIlluminationClassifier(n_images=2,
                                          descent=Descent(max_steps=40, eval_every=10, ridge=0.1),
                                          scoring=SplitScoring(n_repeats=40), seed=0).fit(train)
    return model, test


def test_learns_the_classes_above_chance(fitted):
    model, test = fitted
    acc = evaluate_learned_heldout(model, test, n_renders=2, seed=0)['accuracy']
    # 3 classes (chance 33 %; the per-colour start, lighting no NIR, and the random start,
    # lighting every LED, score near chance on the inner splits); the cue is strong where
    # the light finds it
    assert acc >= 0.55, acc
    assert model.patterns_.shape == (32, 2)
    assert model.patterns_.min() >= 0 and model.patterns_.max() <= 1
    assert model.classifiers_ == {2: model.model_} and model.best_n_patterns_ == 2
    assert 0 <= model.accuracy_by_images_[2] <= 1


def test_the_kept_patterns_score_best_on_the_inner_splits(fitted):
    model, _ = fitted
    scores = model.candidate_scores_
    # the starts and at least the last snapshot of the fine-tuning were scored
    assert 'per_colour' in scores and any('+' in name for name in scores)
    assert model.accuracy_by_images_[2] == scores[model.chosen_] == max(scores.values())
    # the start lights no NIR, where the classes differ: the gradient must have found it
    assert model.best_step_ > 0, scores
    assert scores[model.chosen_] >= scores['per_colour'] + 0.15, scores
    nir = model.patterns_.reshape(8, 4, 2)[:, 3]
    assert nir[:3].max(axis=0).min() > 0.5, nir  # each image lights a cue LED (sites 0-2)


def test_the_inner_estimate_is_the_kept_score_less_the_optimism_of_the_choice(tiny_data):
    """The learned method chooses among its scored candidates on the inner splits, as greedy
    among its columns: its estimate is the kept one's split accuracy less the optimism of
    that choice (`selection_bias`) over every candidate scored."""
    model = LearnedIlluminationClassifier(
        n_images=4, descent=Descent(fine_tune='none'), inner_draws=2,
        scoring=SplitScoring(n_repeats=12), seed=0).fit(tiny_data)
    names = list(model.candidate_scores_)
    splits = model.candidate_split_scores_
    assert set(splits) == set(names) and len(names) > 2
    for name in names:
        assert splits[name].shape == (2 * 12,)              # both draws' splits
        assert splits[name].mean() == pytest.approx(model.candidate_scores_[name])
    groups = split_groups([m for seed in inner_seeds(0, 2) for m in CandidateEvaluator(
        learned_data(tiny_data), mode='joint', n_repeats=12, seed=seed).test_masks])
    k = model.best_n_patterns_
    optimism = selection_optimism(np.vstack([splits[n] for n in names]),
                                  names.index(model.chosen_), groups)
    assert model.optimism_by_images_[k] == pytest.approx(optimism)
    inner = model.inner_estimate_
    assert inner['search_accuracy'] == model.accuracy_by_images_[k]
    assert inner['selection_optimism'] == pytest.approx(optimism)
    assert inner['accuracy'] == pytest.approx(model.accuracy_by_images_[k] - optimism)


def test_without_fine_tuning_a_start_is_kept(tiny_data):
    model = LearnedIlluminationClassifier(n_images=4, descent=Descent(fine_tune='none'),
                                          scoring=SplitScoring(n_repeats=20), seed=0).fit(tiny_data)
    # the default starts, one raking start per split of the paper stage's low sites
    raking = {raking_name(i) for i in
              range(len(low_side_splits(Rig.paper_default().site_positions_mm())))}
    starts = {'random', 'per_colour', 'snr_optimal', 'greedy'} | raking
    assert len(raking) >= 2 and model.chosen_ in starts and model.best_step_ == 0
    assert set(model.candidate_scores_) == starts
    # the greedy start is the greedy search's column on the same data, features and inner
    # splits (the statistics the learned model classifies with)
    greedy = GreedyPatternSelector(mode='per_colour', n_patterns=1, seed=0,
                                   scoring=SplitScoring(n_repeats=20)).fit(
                                       replace(tiny_data, features='intensity_stats'))
    kept = LearnedIlluminationClassifier(n_images=4, starts=Starts(names=('greedy',)),
                                         descent=Descent(fine_tune='none'),
                                         scoring=SplitScoring(n_repeats=20), seed=0).fit(tiny_data)
    np.testing.assert_array_equal(kept.patterns_, site_to_led_patterns(greedy.patterns_, 4))
    assert kept.candidate_scores_['greedy'] == model.candidate_scores_['greedy']


def _horizontal_direction(positions, sites):
    v = positions[sites, :2] / np.hypot(positions[sites, 0], positions[sites, 1])[:, None]
    v = v.mean(axis=0)
    return v / np.linalg.norm(v)


def test_the_raking_sides_are_opposite_groups_of_low_sites():
    paper = Rig.paper_default().site_positions_mm()
    a, b = opposite_low_sides(paper)
    low = np.flatnonzero(paper[:, 2] == paper[:, 2].min())     # the paper's lower ring
    assert len(a) == len(b) == 2 and not set(a) & set(b) and set(a) | set(b) == set(low)
    assert _horizontal_direction(paper, a) @ _horizontal_direction(paper, b) < -0.99
    # a ring of 6 sites at one height: all are low; the halves face each other
    angles = np.deg2rad(np.arange(6) * 60.0 + 10.0)
    ring = np.stack([200 * np.cos(angles), 200 * np.sin(angles), np.full(6, 80.0)], axis=1)
    a, b = opposite_low_sides(ring)
    assert sorted([*a, *b]) == list(range(6)) and len(a) == 3
    assert _horizontal_direction(ring, a) @ _horizontal_direction(ring, b) < -0.99


def test_every_split_of_the_low_sites_once_the_most_opposite_first():
    paper = Rig.paper_default().site_positions_mm()
    splits = low_side_splits(paper)
    # 4 low sites in azimuth order (0, 1, 2, 3): {0, 3} | {1, 2} and {0, 1} | {2, 3}
    assert [(list(a), list(b)) for a, b in splits] == [([0, 3], [1, 2]), ([0, 1], [2, 3])]
    cosines = [_horizontal_direction(paper, a) @ _horizontal_direction(paper, b) for a, b in splits]
    assert cosines == sorted(cosines)
    angles = np.deg2rad(np.arange(6) * 60.0 + 10.0)
    ring = np.stack([200 * np.cos(angles), 200 * np.sin(angles), np.full(6, 80.0)], axis=1)
    assert len(low_side_splits(ring)) == 3     # 6 contiguous halves, each split twice
    P1 = raking_sides_start(paper, 4, 4, None, split=1)
    np.testing.assert_array_equal(np.flatnonzero(P1.reshape(8, 4, 4)[:, :, 0].all(axis=1)), [0, 1])
    with pytest.raises(ValueError, match='split must be in 0..1'):
        raking_sides_start(paper, 4, 4, None, split=2)


def test_the_raking_sides_start_lights_each_side_then_visible_then_nir():
    paper = Rig.paper_default().site_positions_mm()
    a, b = opposite_low_sides(paper)
    P = raking_sides_start(paper, 4, 4, np.random.default_rng(0))
    on = P.reshape(8, 4, 4)                                     # site, channel, image
    assert P.shape == (32, 4) and set(np.unique(P)) == {0.0, 1.0}
    np.testing.assert_array_equal(np.flatnonzero(on[:, :, 0].all(axis=1)), a)
    np.testing.assert_array_equal(np.flatnonzero(on[:, :, 1].all(axis=1)), b)
    assert on[:, :, 0].sum() == 4 * len(a) and on[:, :, 1].sum() == 4 * len(b)
    assert on[:, :3, 2].all() and not on[:, 3, 2].any()        # visible, every site
    assert on[:, 3, 3].all() and not on[:, :3, 3].any()        # NIR, every site
    P8 = raking_sides_start(paper, 4, 8, np.random.default_rng(0))
    np.testing.assert_array_equal(P8[:, :4], P)
    lit_channels = [np.flatnonzero(P8.reshape(8, 4, 8)[:, :, j].any(axis=0)) for j in range(4, 8)]
    assert [list(c) for c in lit_channels] == [[0], [1], [2], [3]]   # each colour alone
    for channels, k in ((3, 4), (4, 3)):
        with pytest.raises(ValueError, match='raking-sides start needs the 4 channels'):
            raking_sides_start(paper, channels, k, None)


def test_the_raking_sides_start_follows_the_rig_and_is_skipped_where_it_cannot_be_made(tiny_data):
    def split_of(model):
        return 0 if model.chosen_ == 'raking_sides' else int(model.chosen_.split('/')[1])

    kept = LearnedIlluminationClassifier(n_images=4, starts=Starts(names=('raking_sides',)),
                                         descent=Descent(fine_tune='none'),
                                         scoring=SplitScoring(n_repeats=10), seed=0).fit(tiny_data)
    assert set(kept.candidate_scores_) == {'raking_sides', 'raking_sides/1'}   # one per split
    np.testing.assert_array_equal(kept.patterns_, raking_sides_start(
        Rig.paper_default().site_positions_mm(), 4, 4, None, split_of(kept)))
    # positions for another stage (the sites in reverse order) give that stage's sides
    flipped = Rig.paper_default().site_positions_mm()[::-1]
    other = LearnedIlluminationClassifier(
        n_images=4, starts=Starts(names=('raking_sides',), site_positions_mm=flipped),
        descent=Descent(fine_tune='none'), scoring=SplitScoring(n_repeats=10),
        seed=0).fit(tiny_data)
    np.testing.assert_array_equal(other.patterns_,
                                  raking_sides_start(flipped, 4, 4, None, split_of(other)))
    # fine-tuning 'raking_sides' descends from the best scored of its splits
    tuned = LearnedIlluminationClassifier(
        n_images=4, starts=Starts(names=('raking_sides',)),
        descent=Descent(fine_tune='raking_sides', max_steps=2, eval_every=2, batch_size=8),
        scoring=SplitScoring(n_repeats=10), seed=0).fit(tiny_data)
    scores = tuned.candidate_scores_
    best = max(('raking_sides', 'raking_sides/1'), key=scores.get)
    assert [h['start'] for h in tuned.history_] == [best] and f'{best}+2' in scores
    # positions of 6 sites for data of 8, or 3 exposures (not one per colour): not made
    for positions, k in ((flipped[:6], 4), (None, 3)):
        model = LearnedIlluminationClassifier(
            n_images=k, starts=Starts(names=('per_colour', 'raking_sides'),
                                      site_positions_mm=positions),
            descent=Descent(fine_tune='none'), scoring=SplitScoring(n_repeats=10),
            seed=0).fit(tiny_data)
        assert set(model.candidate_scores_) == {'per_colour'}
    with pytest.raises(ValueError, match=r'starts.site_positions_mm must be \(n_sites, 3\)'):
        LearnedIlluminationClassifier(n_images=4, starts=Starts(site_positions_mm=[1.0, 2.0, 3.0])
                                      ).fit(tiny_data)


@pytest.mark.parametrize('split_classifier', ['ridge', 'squared_hinge'])
def test_starts_are_scored_by_the_inner_splits_with_the_split_classifier(tiny_data, split_classifier):
    """The inner score of a start is the evaluator's mean split accuracy with that classifier
    (by default the exact SVM; the two differ on these data: 0.300 and 0.3125), on the
    images' own statistics column by column (with the cross-image ones: the whole stack,
    `test_the_model_can_classify_with_the_cross_image_statistics`)."""
    model = LearnedIlluminationClassifier(
        n_images=4, starts=Starts(names=('per_colour',)), descent=Descent(fine_tune='none'),
        scoring=SplitScoring(n_repeats=20, classifier=None if split_classifier == 'squared_hinge'
                             else split_classifier),
        seed=0, ratio_stats=False).fit(tiny_data)
    ev = CandidateEvaluator(replace(tiny_data, features='intensity_stats'), mode='joint',
                            n_repeats=20, seed=0, inner_classifier=split_classifier)
    P = model.patterns_
    expected = float(ev.score(ev.prepare_column(P[:, :3]), P[:, 3:]).mean())
    assert model.candidate_scores_['per_colour'] == pytest.approx(expected, abs=1e-12)


def test_inner_draws_score_a_start_by_the_mean_of_independent_splits(tiny_data):
    """With inner_draws the inner score is the mean over that many evaluators: the first the
    single draw's (seed), the others of seeds of their own."""
    P = np.random.default_rng(4).uniform(0, 1, (32, 4)).astype(np.float32)
    kwargs = dict(n_images=4, starts=Starts(names=(), patterns={'mine': P}),
                  descent=Descent(fine_tune='none'), scoring=SplitScoring(n_repeats=10), seed=3)
    one = LearnedIlluminationClassifier(**kwargs).fit(tiny_data)
    three = LearnedIlluminationClassifier(inner_draws=3, **kwargs).fit(tiny_data)
    seeds = inner_seeds(3, 3)
    assert seeds[0] == 3 and len(set(seeds)) == 3 and inner_seeds(3, 1) == [3]
    data = replace(tiny_data, features='intensity_stats')
    offset = three.model_.ratio_offset
    draws = [float(ev.score_features(stack_features(data, ev.images(P), offset)).mean())
             for ev in (CandidateEvaluator(data, mode='joint', n_repeats=10, seed=s,
                                           inner_classifier='squared_hinge') for s in seeds)]
    assert one.candidate_scores_['mine'] == pytest.approx(draws[0], abs=1e-12)
    assert three.candidate_scores_['mine'] == pytest.approx(np.mean(draws), abs=1e-12)
    assert len(set(draws)) > 1   # the draws differ: the mean is not one of them repeated
    with pytest.raises(ValueError, match='inner_draws'):
        LearnedIlluminationClassifier(inner_draws=0).fit(tiny_data)


def test_an_unknown_split_classifier_is_a_clear_error(tiny_data):
    with pytest.raises(ValueError, match="unknown inner classifier 'svm'; use one of .*squared_hinge"):
        LearnedIlluminationClassifier(n_images=4, scoring=SplitScoring(classifier='svm')
                                      ).fit(tiny_data)


def test_each_descent_draws_its_own_stream(tiny_data):
    """The descent from greedy's columns scores the same after the random start's descent as
    alone (the random start's runs first, so nothing after it can change it): one fit of
    both is the union of the two fits of one each."""
    def fit(tune):
        return LearnedIlluminationClassifier(
            n_images=4, starts=Starts(names=('random', 'greedy')),
            descent=Descent(fine_tune=tune, max_steps=4, eval_every=2, batch_size=8),
            scoring=SplitScoring(n_repeats=10), seed=0).fit(tiny_data).candidate_scores_

    both, greedy_only = fit(('random', 'greedy')), fit('greedy')
    assert [n for n in both if '+' in n] == ['random+2', 'random+4', 'greedy+2', 'greedy+4']
    assert {n: v for n, v in both.items() if not n.startswith('random+')} == greedy_only


def test_a_perfect_inner_score_ends_the_fit(tiny_data, monkeypatch):
    """Nothing after a perfect score could be kept (a tie keeps the earlier candidate), so
    neither greedy's search nor a descent runs after one."""
    monkeypatch.setattr(CandidateEvaluator, 'score', lambda self, ctx, cols, parallel: np.ones(
        (cols.shape[1], len(self.test_masks))))
    monkeypatch.setattr(CandidateEvaluator, 'score_features',
                        lambda self, X: np.ones(len(self.test_masks)))

    def no_search(*args, **kwargs):
        raise AssertionError('greedy searched after a perfect score')

    monkeypatch.setattr(GreedyPatternSelector, 'fit', no_search)
    model = LearnedIlluminationClassifier(n_images=4, descent=Descent(max_steps=4, eval_every=2),
                                          scoring=SplitScoring(n_repeats=5)).fit(tiny_data)
    assert model.candidate_scores_ == {'random': 1.0} and model.history_ == []
    assert model.chosen_ == 'random' and model.best_step_ == 0


def test_the_callback_hears_every_start_column_and_step_and_can_stop_the_fit(tiny_data):
    """Progress as greedy's `callback` gives it (the trainer node's feedback and cancel): each
    start begun and scored in order, greedy's columns while its start is made, each
    descent's snapshots; an exception from the callback ends the fit there."""
    from mux_trainer.learned_method import progress_text
    events = []
    model = LearnedIlluminationClassifier(
        n_images=4, starts=Starts(names=('random', 'greedy')),
        descent=Descent(fine_tune='random', max_steps=4, eval_every=2, batch_size=8),
        scoring=SplitScoring(n_repeats=10), seed=0, callback=events.append).fit(tiny_data)
    kinds = [(e['event'], e.get('start')) for e in events if e['event'] != 'start_candidates']
    assert kinds == [('start', 'random'), ('start_scored', 'random'), ('start', 'greedy'),
                     ('start_column', 'greedy'), ('start_column', 'greedy'),
                     ('start_scored', 'greedy'), ('step', 'random'), ('step', 'random')]
    rounds = [e['done'] for e in events if e['event'] == 'start_candidates']
    assert rounds == list(range(0, 254, 32)), rounds   # greedy's 254 candidates, 32 per task
    assert progress_text(next(e for e in events if e['event'] == 'start_candidates')) == \
        'learned: greedy start, column 1: 0 of 254 candidates scored'
    scored = {e['start']: e['accuracy'] for e in events if e['event'] == 'start_scored'}
    steps = {f"random+{e['step']}": e['accuracy'] for e in events if e['event'] == 'step'}
    assert {**scored, **steps} == model.candidate_scores_
    assert events[-1]['best_accuracy'] == max(model.candidate_scores_.values())
    assert progress_text(events[1]) == f"learned: start 1 of 2 (random): inner accuracy {scored['random']:.3f}"
    assert progress_text(events[3]) == 'learned: greedy start, column 1 of 1: searching'
    assert progress_text(events[-1]).startswith('learned: random + 4 of 4 gradient steps: inner accuracy ')

    class Stop(Exception):
        pass

    def stop_at_the_second_start(event):
        if event['event'] == 'start' and event['index'] == 2:
            raise Stop
    with pytest.raises(Stop):   # greedy's search never ran
        LearnedIlluminationClassifier(n_images=4, starts=Starts(names=('random', 'greedy')),
                                      descent=Descent(fine_tune='none'),
                                      scoring=SplitScoring(n_repeats=10), seed=0,
                                      callback=stop_at_the_second_start).fit(tiny_data)


def test_the_head_is_fitted_on_several_noise_draws(tiny_data, monkeypatch):
    """The final SVM sees head_renders noise draws of every training sample: the inner
    splits' draw first (the head's first draw), then draws that differ from it and from
    each other; data without noise has one draw (the others would be copies)."""
    import mux_trainer.learned.head as head
    fitted_on = []
    fit_linear = head.fit_linear

    def spy(X, y, *args, **kwargs):
        fitted_on.append((np.array(X), np.array(y)))
        return fit_linear(X, y, *args, **kwargs)

    monkeypatch.setattr(head, 'fit_linear', spy)

    def head_data(data, renders):
        LearnedIlluminationClassifier(n_images=4, starts=Starts(names=('per_colour',)),
                                      descent=Descent(fine_tune='none'),
                                      scoring=SplitScoring(n_repeats=5),
                                      head=Head(kind='flat', renders=renders), seed=0).fit(data)
        return fitted_on[-1]

    n = tiny_data.n_samples
    X, y = head_data(tiny_data, 3)
    assert X.shape[0] == 3 * n
    np.testing.assert_array_equal(y, np.tile(tiny_data.labels, 3))
    np.testing.assert_array_equal(head_data(tiny_data, 1)[0], X[:n])
    draws = X.reshape(3, n, -1)
    assert all(np.abs(draws[i] - draws[j]).mean() > 0.01 * np.abs(draws[0]).mean()
               for i, j in ((0, 1), (0, 2), (1, 2)))
    noiseless = replace(tiny_data, noise_a=0.0, noise_b=0.0)
    assert head_data(noiseless, 3)[0].shape[0] == n


def test_site_patterns_expand_to_the_same_images(tiny_data):
    W = np.random.default_rng(0).uniform(0, 1, (8, 2)).astype(np.float32)
    P = site_to_led_patterns(W, tiny_data.n_channels)
    assert P.shape == (32, 8)
    np.testing.assert_allclose(clean_led_images(tiny_data, P), clean_site_images(tiny_data, W),
                               rtol=1e-5, atol=1e-3)


def test_pose_folds_hold_every_pose_out_once():
    poses = np.repeat(np.arange(7), 3)
    folds = pose_folds(poses, 3)
    assert folds.shape == (3, 21)
    assert (folds.sum(axis=0) == 1).all()  # each sample held out by exactly one fold
    for f in folds:  # a pose is held out whole
        assert set(poses[f]).isdisjoint(poses[~f])
    assert pose_folds(poses, 50).shape[0] == 7 and pose_folds(poses, 1).shape[0] == 2


def test_cv_ridge_loss_pays_for_separation_that_holds_on_other_poses():
    rng = np.random.default_rng(0)
    n_poses, per = 8, 10
    y = np.tile(np.repeat(np.arange(2), per), n_poses)
    pose = np.repeat(np.arange(n_poses), 2 * per)
    onehot = jnp.asarray(np.eye(2, dtype=np.float32)[y])
    held_out = jnp.asarray(pose_folds(pose, 4))
    noise = rng.normal(0, 1, (y.size, 3)).astype(np.float32)
    sign = 2.0 * y[:, None] - 1.0
    # the same class offset in every pose, against one whose direction each pose draws anew
    # (it separates the classes within the poses a head is fitted on, and not on others)
    steady = noise + 1.5 * sign * np.array([1, 0, 0], np.float32)
    per_pose = noise + 1.5 * sign * rng.normal(0, 1, (n_poses, 3)).astype(np.float32)[pose]
    loss = {name: float(cv_ridge_loss(jnp.asarray(F), onehot, held_out, 0.01))
            for name, F in (('steady', steady), ('per_pose', per_pose), ('none', noise))}
    assert loss['steady'] < 0.6 * loss['none'], loss
    assert loss['per_pose'] > 0.8 * loss['none'], loss
    # z-scored per fold: light that scales every feature does not pay
    np.testing.assert_allclose(float(cv_ridge_loss(jnp.asarray(10 * steady), onehot, held_out, 0.01)),
                               loss['steady'], rtol=1e-3)
    g = jax.grad(lambda F: cv_ridge_loss(F, onehot, held_out, 0.01))(jnp.asarray(steady))
    assert np.isfinite(np.asarray(g)).all()


def test_numpy_forward_equals_jax_forward(fitted):
    model, test = fitted
    m = model.model_
    images = clean_led_images(test, m.patterns) + np.float32(3.0)
    k, n, p = images.shape
    stacks = images.transpose(1, 0, 2).reshape(n, k, *test.image_shape)
    F_jax = stack_stats(jnp.asarray(images), test.image_shape)
    assert m.ratio_offset > 0   # the default: the cross-image statistics follow
    F_jax = jnp.concatenate([F_jax, stack_ratio_stats(jnp.asarray(images), test.image_shape,
                                                      m.ratio_offset)], axis=1)
    (W, b), = m.layers   # one linear layer on the z-scored statistics
    logits_jax = np.asarray((F_jax - m.feature_mean) / m.feature_scale) @ W + b
    logits_np = m.logits_from_features(m.features(stacks))
    np.testing.assert_allclose(logits_np, logits_jax, rtol=1e-4,
                               atol=1e-4 * np.abs(logits_jax).max())
    np.testing.assert_array_equal(m.predict(stacks), np.argmax(logits_jax, axis=1))
    again = LearnedModel.from_arrays(m.to_arrays())
    np.testing.assert_array_equal(again.logits_from_features(m.features(stacks)), logits_np)
    assert again.class_names == m.class_names


def test_binary_patterns_are_on_off(tiny_data):
    # from the per-colour start (the random start binarised at one image is dark here, so
    # no start: the straight-through descent must run)
    model = LearnedIlluminationClassifier(
        n_images=1, binary=True, starts=Starts(names=('per_colour',)),
        descent=Descent(fine_tune='per_colour', max_steps=10, batch_size=8, eval_every=5),
        scoring=SplitScoring(n_repeats=20), seed=1).fit(tiny_data)
    assert [h['step'] for h in model.history_] == [5, 10]
    assert set(np.unique(model.patterns_)) <= {0.0, 1.0}
    assert model.patterns_.any()


def test_bad_settings_and_inputs_are_refused(tiny_data, fitted):
    one_pose = tiny_data.subset(np.flatnonzero(tiny_data.pose_index == 0))
    with pytest.raises(ValueError, match='at least 2 training poses'):
        LearnedIlluminationClassifier(descent=Descent(max_steps=1)).fit(one_pose)
    with pytest.raises(ValueError, match='n_images'):
        LearnedIlluminationClassifier(n_images=0).fit(tiny_data)
    for changes, message in (({'descent__fine_tune': 'mine'}, 'descent.fine_tune'),
                             ({'descent__fine_tune': ()}, 'descent.fine_tune'),
                             ({'descent__ridge': 0}, 'descent.ridge'),
                             ({'descent__lr': float('nan')}, 'descent.lr'),
                             ({'descent__n_folds': 0}, 'descent.n_folds'),
                             ({'descent__max_steps': -1}, 'steps'),
                             ({'head__renders': 0}, 'head.renders'),
                             ({'head__C': 0}, 'head.C'),
                             ({'starts__names': ('sunlight',)}, 'unknown starts'),
                             ({'scoring__n_repeats': 0}, 'scoring.n_repeats'),
                             ({'rendering__features': 'hog_grid'}, 'rendering.features'),
                             ({'inner_draws': 0}, 'inner_draws')):
        with pytest.raises(ValueError, match=message):
            LearnedIlluminationClassifier().set_params(**changes).fit(tiny_data)
    with pytest.raises(TypeError, match=r'descent=...\) must be a Descent'):
        LearnedIlluminationClassifier(descent={'max_steps': 1}).fit(tiny_data)
    with pytest.raises(ValueError, match='start pattern'):
        LearnedIlluminationClassifier(n_images=2, starts=Starts(patterns={'x': np.ones((8, 2))}),
                                      scoring=SplitScoring(n_repeats=5)).fit(tiny_data)
    model, _ = fitted
    with pytest.raises(ValueError, match='statistics'):
        model.predict_features(np.zeros((3, 5)), 2)
    with pytest.raises(ValueError, match='not available'):
        model.predict_features(np.zeros((3, 18)), 1)
    with pytest.raises(ValueError, match='stacks'):
        model.model_.predict(np.zeros((2, 3, 24, 24)))


def typed_disk_data(n_poses=8, size=24, seed=0):
    """Two object types (a bright and a dim disk anywhere on a dark floor), each in two
    classes (the second reflects 30 % more NIR)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    names = ['bright-matte', 'bright-nir', 'dim-matte', 'dim-nir']
    models, labels, poses = [], [], []
    for k in range(len(names)):
        for p in range(n_poses):
            cy, cx = rng.uniform(7, size - 7, 2)
            disk = ((yy - cy) ** 2 + (xx - cx) ** 2 < 25).astype(np.float32)
            refl = rng.uniform(0.95, 1.05, (4, 8)).astype(np.float32) * (1.0 if k < 2 else 0.5)
            refl[3] *= 1.3 if k % 2 else 1.0
            models.append(8.0 + 90.0 * refl[:, :, None, None] * disk)
            labels.append(k)
            poses.append(p)
    return SearchData.from_models(np.stack(models), labels, poses, names, dimmer=1.0,
                                  noise_a=0.7, noise_b=66.0, hog_config=TINY_HOG)


def test_the_head_is_gated_by_object_type_unless_flat_is_asked():
    """By default one SVM tells the types apart and one per type its classes;
    head='flat' is one SVM over every class."""
    data = typed_disk_data()
    kwargs = dict(n_images=4, starts=Starts(names=('per_colour',)),
                  descent=Descent(fine_tune='none'), scoring=SplitScoring(n_repeats=20), seed=0)
    gated = LearnedIlluminationClassifier(head=Head(renders=2), **kwargs).fit(data)
    flat = LearnedIlluminationClassifier(head=Head(kind='flat', renders=2), **kwargs).fit(data)
    np.testing.assert_array_equal(gated.model_.class_groups, [0, 0, 1, 1])
    assert gated.model_.layers[0][0].shape[1] == 2 + 4 and flat.model_.class_groups is None
    assert flat.model_.layers[0][0].shape[1] == 4
    # the same light (the head does not score candidates); both classify under it
    np.testing.assert_array_equal(gated.patterns_, flat.patterns_)
    images = clean_led_images(data, gated.patterns_)
    for model in (gated, flat):
        assert (model.predict_images(images) == data.labels).mean() > 0.9
    # the gate: the best class of the best type
    k, n, _ = images.shape
    stacks = images.transpose(1, 0, 2).reshape(n, k, *data.image_shape)
    out = gated.model_.logits_from_features(gated.model_.features(stacks))
    best_type = out[:, :2].argmax(axis=1)
    within = out[:, 2:].reshape(-1, 2, 2)[np.arange(n), best_type].argmax(axis=1)
    np.testing.assert_array_equal(gated.predict_images(images), 2 * best_type + within)
    # one class per type: nothing to gate, the flat head
    names = [f'type{c}-only' for c in range(len(data.class_names))]
    ungated = LearnedIlluminationClassifier(head=Head(renders=2), **kwargs).fit(
        replace(data, class_names=names))
    assert ungated.model_.class_groups is None


def test_an_unknown_head_is_a_clear_error(tiny_data):
    with pytest.raises(ValueError, match="head.kind must be one of by_type, flat, got 'mlp'"):
        LearnedIlluminationClassifier(n_images=4, head=Head(kind='mlp')).fit(tiny_data)


def test_the_head_for_a_fixed_light_is_the_estimators_on_every_row_and_scores_held_out_rows(tiny_data):
    """`fit_fixed_light_head` on every training row gives the fitted model's head; on some
    rows it gives a head that has not seen the others and per-class scores for them (the
    held-out answers calibration fits on)."""
    model = LearnedIlluminationClassifier(n_images=4, starts=Starts(names=('per_colour',)),
                                          descent=Descent(fine_tune='none'), head=Head(renders=2),
                                          scoring=SplitScoring(n_repeats=10), seed=2).fit(tiny_data)
    rows = np.arange(tiny_data.n_samples)
    again, scores = fit_fixed_light_head(tiny_data, model.patterns_, rows, rows[:5],
                                         head=Head(renders=2), seed=2)
    for name, a in model.model_.to_arrays().items():
        np.testing.assert_array_equal(again.to_arrays()[name], a, err_msg=name)
    assert scores.shape == (5, len(tiny_data.class_names))
    # hold out pose 0 of every class: fitted on the rest, scored on it
    held = tiny_data.pose_index == 0
    part, held_scores = fit_fixed_light_head(tiny_data, model.patterns_, ~held, held,
                                             head=Head(renders=2), seed=2)
    assert held_scores.shape == (held.sum(), len(tiny_data.class_names))
    assert not np.array_equal(part.layers[0][0], again.layers[0][0])
    # scored on the inner splits' noise draw (the fitted model's evaluator's)
    X = stack_features(model.evaluator_.data, model.evaluator_.images(model.patterns_),
                       model.model_.ratio_offset)
    np.testing.assert_allclose(held_scores, part.scores_from_features(X[held]), rtol=1e-12)
    with pytest.raises(ValueError, match='no training rows'):
        fit_fixed_light_head(tiny_data, model.patterns_, rows[:0], rows)
    with pytest.raises(ValueError, match=r'patterns must be \(32, k\)'):
        fit_fixed_light_head(tiny_data, model.patterns_[:8], rows, rows)


def test_the_settings_are_grouped_and_follow_the_scikit_learn_protocol():
    """At most 12 constructor parameters; the groups' fields read and set as group__field,
    a change replacing the group (the default instance stays as it was); clone keeps them."""
    from sklearn.base import clone
    model = LearnedIlluminationClassifier()
    params = model.get_params(deep=False)
    assert len(params) <= 12, sorted(params)
    deep = model.get_params(deep=True)
    assert deep['descent__max_steps'] == 0 and deep['head__renders'] == 6
    assert deep['starts__names'] == ('random', 'per_colour', 'snr_optimal', 'greedy', 'raking_sides')
    assert deep['rendering__features'] == 'intensity_stats'
    default = model.descent
    model.set_params(descent__max_steps=7, head__kind='flat', scoring__n_repeats=9)
    assert model.descent.max_steps == 7 and default.max_steps == 0
    assert model.head == Head(kind='flat') and model.scoring.n_repeats == 9
    copy = clone(model)
    assert copy.descent == model.descent and copy.head == model.head
    with pytest.raises(ValueError, match='has no field'):
        model.set_params(descent__steps=3)


def test_the_descents_adam_is_bias_corrected_with_eps_outside_the_root():
    """Adam (Kingma & Ba) on fixed gradients, against the closed form in float64:
    p_t = p_{t-1} - lr * m_hat / (sqrt(v_hat) + eps), m_hat = m / (1 - b1^t),
    v_hat = v / (1 - b2^t)."""
    import optax
    from mux_trainer.learned import adam
    rng = np.random.default_rng(0)
    grads = rng.normal(0, 1e-7, (5, 6)).astype(np.float32)   # near eps: where it sits shows
    opt = adam(0.2)
    p = jnp.zeros(6, jnp.float32)
    state = opt.init(p)
    m = v = ref = np.zeros(6)
    for t, g in enumerate(grads, start=1):
        updates, state = opt.update(jnp.asarray(g), state, p)
        p = optax.apply_updates(p, updates)
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g.astype(np.float64) ** 2
        ref = ref - 0.2 * (m / (1 - 0.9 ** t)) / (np.sqrt(v / (1 - 0.999 ** t)) + 1e-8)
    np.testing.assert_allclose(np.asarray(p), ref, rtol=1e-4)
