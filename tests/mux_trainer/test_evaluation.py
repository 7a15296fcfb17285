import numpy as np
import pytest

from mux_trainer.candidate_patterns import gray_code, site_pattern_candidates
from mux_trainer.evaluation import CandidateEvaluator, score_candidate_chunk
from mux_trainer.reference import reference_candidate_scores
from mux_trainer.rendering import clean_led_images, clean_site_images


def test_candidates_are_the_254_patterns_in_gray_code_order():
    W = site_pattern_candidates()
    assert W.shape == (8, 254)
    lit = W.sum(axis=0)
    assert lit.min() == 1 and lit.max() == 7
    assert len({w.tobytes() for w in W.T}) == 254
    steps = np.abs(np.diff(W, axis=1)).sum(axis=0)
    assert np.mean(steps == 1) > 0.99  # one site per step, except around the skipped all-on
    g = gray_code(4)
    assert all(bin(a ^ b).count('1') == 1 for a, b in zip(g[:-1], g[1:]))


def test_incremental_render_matches_direct_render(tiny_data):
    W = site_pattern_candidates()[:, :40]
    direct = clean_site_images(tiny_data, W)
    step = direct.reshape(40, 4, *direct.shape[1:])
    clean = clean_site_images(tiny_data, W[:, :1])
    for j in range(1, 40):
        for site in np.flatnonzero(W[:, j] - W[:, j - 1]):
            clean += (W[site, j] - W[site, j - 1]) * tiny_data.basis[site]
        np.testing.assert_allclose(clean, step[j], rtol=1e-5, atol=1e-3)


def test_led_render_is_the_sum_of_the_lit_leds(tiny_data):
    P = np.zeros((32, 2), np.float32)
    P[[0, 5], 0] = 1
    P[7, 1] = 0.5
    imgs = clean_led_images(tiny_data, P)
    np.testing.assert_allclose(imgs[0], tiny_data.basis[0, 0] + tiny_data.basis[1, 1])
    np.testing.assert_allclose(imgs[1], 0.5 * tiny_data.basis[1, 3])


@pytest.mark.parametrize('prev', [None, 'one column'])
def test_fast_scores_equal_the_straightforward_reference(tiny_data, prev):
    W = site_pattern_candidates()
    cols = None if prev is None else W[:, [100]]
    ev = CandidateEvaluator(tiny_data, n_repeats=12, seed=5)
    fast = ev.score(ev.prepare_column(cols), W[:, :24])
    slow = reference_candidate_scores(tiny_data, 'per_colour', cols, W[:, :24], seed=5,
                                      n_repeats=12, classifier='ridge')
    np.testing.assert_array_equal(fast, slow)
    assert len(np.unique(fast.mean(axis=1))) > 3  # candidates differ


def test_linear_svm_inner_classifier_equals_reference(tiny_data):
    all_w = site_pattern_candidates()
    W, prev = all_w[:, :3], all_w[:, [10]]
    ev = CandidateEvaluator(tiny_data, n_repeats=4, seed=1, inner_classifier='linear_svm')
    fast = ev.score(ev.prepare_column(prev), W)
    slow = reference_candidate_scores(tiny_data, 'per_colour', prev, W, seed=1,
                                      n_repeats=4, classifier='linear_svm')
    np.testing.assert_array_equal(fast, slow)


def test_scores_reproducible_and_independent_of_jobs_and_chunking(tiny_data):
    W = site_pattern_candidates()[:, :20]
    a = CandidateEvaluator(tiny_data, n_repeats=10, seed=2, chunk_size=7)
    b = CandidateEvaluator(tiny_data, n_repeats=10, seed=2, chunk_size=7, n_jobs=2)
    c = CandidateEvaluator(tiny_data, n_repeats=10, seed=3, chunk_size=7)
    sa = a.score(a.prepare_column(W[:, [3]]), W)
    np.testing.assert_array_equal(sa, b.score(b.prepare_column(W[:, [3]]), W))
    assert not np.array_equal(sa, c.score(c.prepare_column(W[:, [3]]), W))


def test_common_random_numbers_within_a_column(tiny_data):
    """A candidate scores the same alone or among others: one noise draw per column."""
    W = site_pattern_candidates()[:, :9]
    ev = CandidateEvaluator(tiny_data, n_repeats=10, seed=4)
    ctx = ev.prepare_column(None)
    together = score_candidate_chunk(tiny_data, ctx, W)
    alone = score_candidate_chunk(tiny_data, ctx, W[:, [8]])
    np.testing.assert_allclose(together[8], alone[0])
    # and the next column's candidate noise is a different draw
    assert not np.array_equal(ev.candidate_noise(0), ev.candidate_noise(1))


def test_bad_mode_and_shapes_fail_clearly(tiny_data):
    with pytest.raises(ValueError, match='unknown mode'):
        CandidateEvaluator(tiny_data, mode='spectral')
    with pytest.raises(ValueError, match='unknown inner classifier'):
        CandidateEvaluator(tiny_data, inner_classifier='forest')


def test_fused_noise_is_the_numpy_noise_bit_for_bit(tiny_data):
    from mux_trainer.rendering import add_noise, add_noise_numpy, standard_normal
    rng = np.random.default_rng(3)
    clean = rng.uniform(-5, 1100, (4, tiny_data.n_samples, 24 * 24)).astype(np.float32)
    z = standard_normal(rng, clean.shape)
    fused = add_noise(tiny_data, clean, z)
    np.testing.assert_array_equal(fused, add_noise_numpy(tiny_data, clean, z))
    assert fused.min() >= 0 and fused.max() <= tiny_data.max_level
    out = np.empty_like(clean)
    assert add_noise(tiny_data, clean, z, out=out) is out
    np.testing.assert_array_equal(out, fused)
    # broadcast noise (not the search's layout) goes through numpy
    np.testing.assert_array_equal(add_noise(tiny_data, clean, z[:1]),
                                  add_noise_numpy(tiny_data, clean, z[:1]))
