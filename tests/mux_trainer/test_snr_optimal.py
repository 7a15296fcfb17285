"""SNR-optimal multiplexing search and Hadamard S-matrix codes."""
import numpy as np
import pytest
from sklearn.base import clone

from mux_trainer.snr_optimal import (SnrOptimalMultiplexer, compare_with_hadamard,
                                     hadamard_s_matrix, image_noise_variance, multiplexing_mse,
                                     noise_coefficients, s_matrix_for_sites)


def test_mse_of_identity_is_the_single_image_variance():
    # each image lights one site: variance sigma_p2 * R + sigma_r2, demultiplexing is trivial
    assert multiplexing_mse(np.eye(8), 0.94, 117.37, 50.0) == pytest.approx(0.94 * 50 + 117.37)
    assert multiplexing_mse(np.eye(8), 0.94, 117.37, 50.0, noise_scale=0.25) == pytest.approx(
        0.25 * (0.94 * 50 + 117.37))


def test_mse_formula_on_a_small_case_by_hand():
    # 2 sites, images: {site 0}, {sites 0, 1}
    W = np.array([[1.0, 1.0], [0.0, 1.0]])
    sp, sr, R = 0.5, 2.0, 4.0
    var = np.array([sp * R * 1 + sr, sp * R * 2 + sr])   # 4, 6
    np.testing.assert_allclose(image_noise_variance(W, sp, sr, R), var)
    # measurements a = W^T i: i0 = a0, i1 = a1 - a0 -> var(i0) = 4, var(i1) = 6 + 4
    assert multiplexing_mse(W, sp, sr, R) == pytest.approx((4 + 10) / 2)


def test_singular_matrix_has_infinite_mse():
    W = np.eye(3)
    W[:, 2] = W[:, 1]
    assert multiplexing_mse(W, 0.0, 1.0, 10.0) == np.inf


@pytest.mark.parametrize("n", [1, 3, 7, 15])
def test_hadamard_s_matrix_structure_and_theoretical_gain(n):
    S = hadamard_s_matrix(n)
    assert S.shape == (n, n) and set(np.unique(S)) <= {0.0, 1.0}
    np.testing.assert_array_equal(S.sum(axis=0), (n + 1) // 2)
    np.testing.assert_array_equal(S.sum(axis=1), (n + 1) // 2)
    # signal-independent noise: MSE ratio identity / S = (n + 1)^2 / (4 n)
    ratio = multiplexing_mse(np.eye(n), 0.0, 3.0, 100.0) / multiplexing_mse(S, 0.0, 3.0, 100.0)
    assert ratio == pytest.approx((n + 1) ** 2 / (4 * n))


def test_hadamard_rejects_other_orders():
    with pytest.raises(ValueError, match="2\\^m - 1"):
        hadamard_s_matrix(8)


def test_s_matrix_for_eight_sites():
    W = s_matrix_for_sites(8)
    np.testing.assert_array_equal(W[:7, :7], hadamard_s_matrix(7))
    assert W[7, 7] == 1 and W[7, :7].sum() == 0 and W[:7, 7].sum() == 0
    assert np.linalg.matrix_rank(W) == 8


def test_search_starts_from_identity_and_never_gets_worse():
    m = SnrOptimalMultiplexer(noise=(0.94, 117.37), n_iter=0, start="identity").fit(50.0)
    np.testing.assert_array_equal(m.W_, np.eye(8))
    assert m.mse_ == m.mse_identity_ and m.n_accepted_ == 0
    m = SnrOptimalMultiplexer(noise=(0.94, 117.37), n_iter=3000, start="identity").fit(50.0)
    assert m.mse_ <= m.mse_identity_
    mses = [v for _, v in m.history_]
    # every kept step is a real gain, not a rounding tie (relative 1e-9)
    assert mses[0] == m.mse_identity_ and all(b < a * (1 - 1e-9) for a, b in zip(mses, mses[1:]))
    assert m.mse_ == pytest.approx(multiplexing_mse(m.W_, 0.94, 117.37, 50.0))


@pytest.mark.parametrize("seed", range(6))
def test_default_search_reaches_the_s_code_for_signal_independent_noise(seed):
    # the S-code is optimal here (gain 2.29 over the identity for 7 sites); the default
    # search starts from it too, so it can never end above it, on any CPU and BLAS kernel
    m = SnrOptimalMultiplexer(n_sites=7, noise=(0.0, 10.0), n_iter=2000, seed=seed).fit(100.0)
    S_mse = multiplexing_mse(hadamard_s_matrix(7), 0.0, 10.0, 100.0)
    assert m.mse_ <= S_mse * (1 + 1e-9)
    assert m.mse_ < 0.5 * m.mse_identity_
    assert set(np.unique(m.W_)) == {0.0, 1.0} and m.W_.dtype == np.float32


@pytest.mark.parametrize("n_sites", [3, 5, 8, 12])
@pytest.mark.parametrize("level", [10.0, 20.0, 50.0])
def test_default_search_is_never_worse_than_the_s_code(n_sites, level):
    sp, sr = 0.94, 117.37
    s_mse = multiplexing_mse(s_matrix_for_sites(n_sites), sp, sr, level)
    m = SnrOptimalMultiplexer(n_sites=n_sites, noise=(sp, sr), n_iter=300, seed=3).fit(level)
    assert m.mse_ <= s_mse * (1 + 1e-9) and m.mse_ <= m.mse_identity_
    assert np.linalg.cond(m.W_) < 100 and m.W_.any(axis=0).all()


def test_paper_search_from_the_identity_improves_on_it_for_signal_independent_noise():
    # how far the paper's search gets from the identity depends on the seed's luck (6.41
    # or 4.44 of the identity's 10 were seen for one seed, before ties were refused); any
    # seed finds some gain within 5000 flips
    m = SnrOptimalMultiplexer(n_sites=7, noise=(0.0, 10.0), n_iter=5000, seed=1,
                              start="identity").fit(100.0)
    assert m.mse_ < 0.9 * m.mse_identity_ and m.n_accepted_ >= 1


def test_rounding_ties_do_not_steer_the_search(monkeypatch):
    # equal MSEs that differ in the last bit (as they do between BLAS kernels) must give the
    # same search: perturb every MSE by a few ulps and compare paths
    import mux_trainer.snr_optimal as so

    exact = so.multiplexing_mse
    a = SnrOptimalMultiplexer(n_sites=7, noise=(0.0, 10.0), n_iter=3000, seed=1,
                              start="identity").fit(100.0)
    jitter = np.random.default_rng(0)

    def jittered(*args, **kwargs):
        v = exact(*args, **kwargs)
        return v * (1 + 4e-16 * jitter.integers(-4, 5)) if np.isfinite(v) else v

    monkeypatch.setattr(so, "multiplexing_mse", jittered)
    b = SnrOptimalMultiplexer(n_sites=7, noise=(0.0, 10.0), n_iter=3000, seed=1,
                              start="identity").fit(100.0)
    np.testing.assert_array_equal(a.W_, b.W_)
    assert [i for i, _ in a.history_] == [i for i, _ in b.history_]


def test_identity_stays_optimal_when_photon_noise_dominates():
    # sigma_p2 * R >> sigma_r2: lighting more sites only adds noise
    m = SnrOptimalMultiplexer(noise=(1.0, 0.01), n_iter=2000, start="identity").fit(1000.0)
    np.testing.assert_array_equal(m.W_, np.eye(8))


@pytest.mark.parametrize("max_cond", [3.0, 100.0])
def test_condition_limit_and_no_dark_image_are_respected(max_cond):
    m = SnrOptimalMultiplexer(noise=(0.0, 10.0), n_iter=3000, max_cond=max_cond, seed=2).fit(100.0)
    assert np.linalg.cond(m.W_) < max_cond and m.cond_ < max_cond
    assert m.W_.any(axis=0).all()
    # the constraint binds: the unconstrained optimum (S-like codes) has cond > 3
    if max_cond == 3.0:
        assert np.linalg.cond(s_matrix_for_sites(8)) > 3.0


def test_search_is_deterministic_for_a_seed():
    a = SnrOptimalMultiplexer(noise="sigma3", n_iter=2000, seed=5, start="identity").fit(40.0)
    b = clone(a).fit(40.0)
    c = SnrOptimalMultiplexer(noise="sigma3", n_iter=2000, seed=6, start="identity").fit(40.0)
    np.testing.assert_array_equal(a.W_, b.W_)
    assert a.history_ == b.history_
    assert a.history_ != c.history_


def test_more_images_than_sites_and_columns():
    m = SnrOptimalMultiplexer(n_sites=4, n_images=6, noise=(0.0, 1.0), n_iter=1000).fit(10.0)
    assert m.W_.shape == (4, 6)
    np.testing.assert_array_equal(m.columns(2), m.W_[:, :2])
    with pytest.raises(ValueError, match="k must be"):
        m.columns(7)


def test_bad_arguments_are_explained():
    with pytest.raises(ValueError, match=r"W_\[:, :3\]"):
        SnrOptimalMultiplexer(n_images=3, noise=(0, 1)).fit(10.0)
    with pytest.raises(ValueError, match="needs a noise model"):
        SnrOptimalMultiplexer(noise="none").fit(10.0)
    with pytest.raises(ValueError, match="mean_level"):
        SnrOptimalMultiplexer(noise=(0, 1)).fit(-1.0)
    with pytest.raises(ValueError, match="noise must be"):
        noise_coefficients(3.0)


def test_presets_resolve_to_the_papers_values():
    assert noise_coefficients("sigma3") == pytest.approx((0.94, 117.37))
    assert noise_coefficients({"sigma_p2": 0.25, "sigma_r2": 8.35}) == (0.25, 8.35)


def test_compare_with_hadamard_reports_side_by_side():
    r = compare_with_hadamard(8, noise=(0.0, 1.0), mean_level=100.0, n_iter=10000)
    assert r["mse"]["identity"] == pytest.approx(1.0)
    assert r["s_matrix_order"] == 7
    assert r["s_matrix_theory_gain"] == pytest.approx(64 / 28)
    # 8 sites = S_7 plus one site alone: (7 * 7/16 + 1) / 8 of the identity's MSE
    assert r["mse"]["s_matrix"] == pytest.approx((7 * 7 / 16 + 1) / 8)
    assert r["gain_vs_identity"]["snr_optimal"] > 1.0
    assert r["mse"]["snr_optimal_from_both"] <= r["mse"]["s_matrix"] * (1 + 1e-9)


def test_start_from_s_matrix_is_never_worse_than_the_s_code():
    sp, sr, level = 0.94, 117.37, 20.0
    s_mse = multiplexing_mse(s_matrix_for_sites(8), sp, sr, level)
    m = SnrOptimalMultiplexer(noise=(sp, sr), n_iter=500, start="s_matrix").fit(level)
    assert m.history_[0][1] == pytest.approx(s_mse) and m.mse_ <= s_mse
    both = SnrOptimalMultiplexer(noise=(sp, sr), n_iter=500, start="both").fit(level)
    ident = SnrOptimalMultiplexer(noise=(sp, sr), n_iter=500, start="identity").fit(level)
    assert both.mse_ <= min(s_mse, ident.mse_ + 1e-12)
    with pytest.raises(ValueError, match="start must be"):
        SnrOptimalMultiplexer(noise=(sp, sr), start="random").fit(level)
    # more images than sites: the S-code's columns repeat, like the identity's
    wide = SnrOptimalMultiplexer(n_images=10, noise=(sp, sr), n_iter=0, start="s_matrix").fit(level)
    np.testing.assert_array_equal(wide.W_[:, 8:], s_matrix_for_sites(8)[:, :2])


def test_command_line_prints_the_comparison(capsys):
    from mux_trainer.snr_optimal import main

    assert main(["--noise", "0,1", "--mean-level", "100", "--iterations", "300"]) == 0
    out = capsys.readouterr().out
    assert "S-code" in out and "1.969" in out   # S_7 + 1 gain for signal-independent noise
