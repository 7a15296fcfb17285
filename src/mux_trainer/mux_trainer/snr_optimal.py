"""SNR-optimal multiplexing matrices: the paper's baseline (Sect. "SNR-Optimal Illumination Patterns").

Multiplexing theory (Schechner et al. 2007; Alterman et al. 2010) asks for the binary
illumination matrix from which the single-site images are recovered (demultiplexed) with
the lowest mean squared error. Here ``W`` is a *site matrix* (n_sites, n_images) as
everywhere in lightstage: column j is the site pattern of image j. Its measurement
matrix in the papers' notation is ``W.T``. With the affine noise model, image j (sites
lit: column sum of W) has noise variance

    Sigma_jj = noise_scale * (sigma_p2 * mean_level * sum_i W[i, j] + sigma_r2)

where ``mean_level`` is the mean gray level of a one-site image (the paper's R-bar times
the exposure), and the demultiplexing error is

    MSE = (1 / n_sites) * tr[(W Sigma^-1 W^T)^-1].

``SnrOptimalMultiplexer`` runs the paper's stochastic search: start from the identity;
each iteration flips random entries of the best matrix so far; reject results with an
all-dark image or ``cond(W) >= max_cond`` (the authors' code: 100); keep the lowest MSE.
From the identity alone the search can stop far above the S-code's MSE (the identity's
neighbourhood is rugged), so by default it also runs from the S-code and keeps the
better result: never worse than the S-code wherever one exists. ``start="identity"``
is the paper's search as published. A trial must lower the MSE by a relative 1e-9 to
be kept: mathematically equal MSEs (permuted codes) differ in their last bits between
BLAS kernels, and accepting such a tie sent the search down a different path on
another CPU.
The result is square by default (8 sites, 8 images). As in the paper, classifiers for
fewer images use its first k columns (``W_[:, :k]``, "shortcut evaluation"): fewer than
n_sites images cannot be demultiplexed, so the MSE is only defined for the full matrix.

``hadamard_s_matrix(n)`` gives the S-matrix code (n = 2^m - 1), optimal for
signal-independent noise, where it lowers the MSE by (n + 1)^2 / (4 n) relative to the
identity; ``compare_with_hadamard`` reports the MSEs side by side.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
from lightstage_physics.rig import DEFAULT_DIMMER, N_SITES
from sklearn.base import BaseEstimator

__all__ = [
    "multiplexing_mse", "image_noise_variance", "SnrOptimalMultiplexer", "hadamard_s_matrix",
    "s_matrix_for_sites", "compare_with_hadamard", "noise_coefficients", "single_site_mean_level",
]


# A trial is kept only if it lowers the MSE by this fraction: equal MSEs computed through
# different BLAS kernels differ in the last bits, and a "gain" of one ulp must not steer
# the search (it did: OpenBLAS Haswell and Sandybridge took different paths from one seed).
_MIN_RELATIVE_GAIN = 1e-9


def noise_coefficients(noise) -> tuple[float, float]:
    """(sigma_p2, sigma_r2) from a preset name ("sigma1".."sigma3"), a NoiseModel-like
    object, a dict or a (sigma_p2, sigma_r2) pair."""
    if isinstance(noise, str):
        from lightstage_physics.noise import preset

        model = preset(noise)
        if model is None:
            raise ValueError(
                "the SNR-optimal search needs a noise model; noise 'none' has no noise to "
                "optimise against: choose sigma1, sigma2, sigma3 or give (sigma_p2, sigma_r2)")
        noise = model
    if isinstance(noise, dict):
        pair = (noise.get("sigma_p2"), noise.get("sigma_r2"))
    elif hasattr(noise, "sigma_p2") and hasattr(noise, "sigma_r2"):
        pair = (noise.sigma_p2, noise.sigma_r2)
    else:
        try:
            pair = tuple(noise)
        except TypeError:
            pair = ()
    if len(pair) != 2 or any(v is None for v in pair):
        raise ValueError(
            f"noise must be a preset name, a NoiseModel, a dict or (sigma_p2, sigma_r2); got {noise!r}")
    sigma_p2, sigma_r2 = float(pair[0]), float(pair[1])
    if not (np.isfinite(sigma_p2) and np.isfinite(sigma_r2)) or sigma_p2 < 0 or sigma_r2 < 0:
        raise ValueError(f"sigma_p2 and sigma_r2 must be finite and >= 0, got {sigma_p2}, {sigma_r2}")
    if sigma_p2 == 0 and sigma_r2 == 0:
        raise ValueError("noise variance is zero everywhere; the MSE criterion needs noise")
    return sigma_p2, sigma_r2


def single_site_mean_level(models, dimmer: float = DEFAULT_DIMMER) -> float:
    """Mean gray level of a one-site image: mean of the relightable models times the dimmer.

    ``models``: a ModelSet or its array (n_samples, 4, 8, H, W) of single-LED images.
    """
    arr = getattr(models, "models", models)
    return float(np.mean(arr, dtype=np.float64) * dimmer)


def image_noise_variance(W, sigma_p2: float, sigma_r2: float, mean_level: float,
                         noise_scale: float = 1.0) -> np.ndarray:
    """Noise variance of each image (n_images,) of site matrix W (n_sites, n_images)."""
    W = np.asarray(W, dtype=np.float64)
    return noise_scale * (sigma_p2 * mean_level * W.sum(axis=0) + sigma_r2)


def multiplexing_mse(W, sigma_p2: float, sigma_r2: float, mean_level: float,
                     noise_scale: float = 1.0) -> float:
    """(1/n_sites) tr[(W Sigma^-1 W^T)^-1] for site matrix W (n_sites, n_images); inf if W
    cannot be demultiplexed (rank < n_sites)."""
    W = np.asarray(W, dtype=np.float64)
    if W.ndim != 2:
        raise ValueError(f"W must be a matrix (n_sites, n_images), got shape {W.shape}")
    var = image_noise_variance(W, sigma_p2, sigma_r2, mean_level, noise_scale)
    if np.any(var <= 0):
        raise ValueError("image noise variance must be > 0 (sigma_r2 > 0 or every image lit)")
    fisher = (W / var) @ W.T
    try:
        inv = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:
        return float("inf")
    trace = float(np.trace(inv))
    # a numerically singular W gives a huge or negative trace: treat as not invertible
    if not np.isfinite(trace) or trace <= 0 or np.linalg.cond(fisher) > 1e12:
        return float("inf")
    return trace / W.shape[0]


class SnrOptimalMultiplexer(BaseEstimator):
    """Stochastic search for the binary site matrix with the lowest demultiplexing MSE.

    Parameters
    ----------
    n_sites : int
        Illumination sites (rows of W).
    n_images : int or None
        Images (columns of W); None means n_sites. Must be >= n_sites.
    noise : str, NoiseModel, dict or (sigma_p2, sigma_r2)
        The camera noise setting the matrix is optimised for.
    n_iter : int
        Perturbations tried.
    max_flips : int
        Each perturbation flips 1..max_flips random entries of the best matrix so far.
        The identity is a local optimum for one or two flips (the search would never
        leave it), so the default allows up to 8.
    max_cond : float
        Matrices with condition number >= max_cond are rejected (authors' code: 100).
    noise_scale : float
        Variance factor (e.g. of a downscale); scales the MSE, never changes the optimum.
    start : {"both", "identity", "s_matrix"}
        Where the search starts: the identity (the paper), the S-code of
        ``s_matrix_for_sites`` (its columns repeated, like the identity's, when there are
        more images than sites), or both, n_iter each, keeping the better (default).
        From the identity the stochastic search can end far below the S-code's gain when
        photon noise is weak (see docs/CLASSIFIER.md); "both" never does.
    seed : int
        The search is deterministic for a seed.

    Fitted attributes: ``W_`` (n_sites, n_images) float32 in {0, 1}; ``mse_``;
    ``mse_identity_``; ``cond_``; ``n_accepted_`` (improvements found);
    ``history_`` (iteration, mse) of every improvement.
    """

    def __init__(self, n_sites=N_SITES, n_images=None, noise="sigma3", n_iter=20000, max_flips=8,
                 max_cond=100.0, noise_scale=1.0, start="both", seed=0):
        self.n_sites = n_sites
        self.n_images = n_images
        self.noise = noise
        self.n_iter = n_iter
        self.max_flips = max_flips
        self.max_cond = max_cond
        self.noise_scale = noise_scale
        self.start = start
        self.seed = seed

    def _identity(self) -> np.ndarray:
        n = int(self.n_sites)
        m = n if self.n_images is None else int(self.n_images)
        if n < 1:
            raise ValueError(f"n_sites must be >= 1, got {self.n_sites}")
        if m < n:
            raise ValueError(
                f"n_images={m} < n_sites={n}: fewer images than sites cannot be demultiplexed, "
                "so the MSE is undefined. Search the square matrix (n_images=None) and use "
                f"its first {m} columns, W_[:, :{m}], as the paper does")
        if int(self.max_flips) < 1 or int(self.n_iter) < 0 or not self.max_cond > 1:
            raise ValueError("need max_flips >= 1, n_iter >= 0 and max_cond > 1")
        # identity, repeated if there are more images than sites
        return np.eye(n, dtype=np.float64)[:, np.arange(m) % n]

    def _starts(self, identity: np.ndarray) -> list[np.ndarray]:
        starts = {"identity": ["identity"], "s_matrix": ["s_matrix"],
                  "both": ["identity", "s_matrix"]}.get(self.start)
        if starts is None:
            raise ValueError(f"start must be 'identity', 's_matrix' or 'both', got {self.start!r}")
        n, m = identity.shape
        s_code = s_matrix_for_sites(n).astype(np.float64)[:, np.arange(m) % n]
        return [identity if s == "identity" else s_code for s in starts]

    def fit(self, mean_level, y=None):
        """Search W for images whose one-site mean gray level is ``mean_level``; returns self."""
        mean_level = float(mean_level)
        if not np.isfinite(mean_level) or mean_level < 0:
            raise ValueError(f"mean_level must be a finite gray level >= 0, got {mean_level}")
        sigma_p2, sigma_r2 = noise_coefficients(self.noise)
        identity = self._identity()
        starts = self._starts(identity)

        def mse(W):
            return multiplexing_mse(W, sigma_p2, sigma_r2, mean_level, self.noise_scale)

        self.mse_identity_ = mse(identity)
        rng = np.random.default_rng(self.seed)
        results = [self._search(W0, mse, rng) for W0 in starts]
        best, best_mse, history = min(results, key=lambda r: r[1])
        self.W_ = best.astype(np.float32)
        self.mse_ = best_mse
        self.cond_ = float(np.linalg.cond(best))
        self.n_accepted_ = len(history) - 1
        self.history_ = history
        return self

    def _search(self, best: np.ndarray, mse, rng: np.random.Generator):
        """Stochastic bit-flip descent from ``best``: (W, mse, [(iteration, mse), ...])."""
        n, m = best.shape
        # a start beyond the condition limit (the S-code under a tight max_cond) counts as
        # no solution: the search may still leave it for an allowed matrix
        best_mse = mse(best) if np.linalg.cond(best) < self.max_cond else float("inf")
        history = [(0, best_mse)]
        flips = rng.integers(1, int(self.max_flips) + 1, size=int(self.n_iter))
        for it in range(int(self.n_iter)):
            trial = best.copy()
            idx = rng.choice(n * m, size=min(int(flips[it]), n * m), replace=False)
            trial.flat[idx] = 1.0 - trial.flat[idx]
            if not trial.any(axis=0).all():  # an image with nothing lit
                continue
            value = mse(trial)
            # the condition check only matters for a would-be improvement (cheaper order,
            # same result as checking it first)
            if value < best_mse * (1.0 - _MIN_RELATIVE_GAIN) and np.linalg.cond(trial) < self.max_cond:
                best, best_mse = trial, value
                history.append((it + 1, value))
        return best, best_mse, history

    def columns(self, k: int) -> np.ndarray:
        """The first k columns (the patterns of a k-image classifier, paper's shortcut)."""
        W = self.W_
        if not 1 <= k <= W.shape[1]:
            raise ValueError(f"k must be 1..{W.shape[1]}, got {k}")
        return W[:, :k].copy()


def hadamard_s_matrix(n: int) -> np.ndarray:
    """The S-matrix code of order n = 2^m - 1 (0/1 entries, (n + 1)/2 ones per row/column).

    Built from the Sylvester Hadamard matrix H of order n + 1: drop its first row and
    column and map +1 -> 0, -1 -> 1.
    """
    n = int(n)
    if n < 1 or (n + 1) & n:
        raise ValueError(f"S-matrices exist for n = 2^m - 1 (1, 3, 7, 15, ...), got {n}")
    H = scipy.linalg.hadamard(n + 1)
    return ((1 - H[1:, 1:]) // 2).astype(np.float32)


def s_matrix_for_sites(n_sites: int) -> np.ndarray:
    """An invertible code for any n_sites: the largest S-matrix that fits, identity for the rest.

    For the rig's 8 sites: S_7 on sites 0..6 (4 lit per image) and site 7 alone.
    """
    n_sites = int(n_sites)
    order = 1
    while 2 * (order + 1) - 1 <= n_sites:
        order = 2 * (order + 1) - 1
    W = np.zeros((n_sites, n_sites), dtype=np.float32)
    W[:order, :order] = hadamard_s_matrix(order)
    W[order:, order:] = np.eye(n_sites - order, dtype=np.float32)
    return W


def compare_with_hadamard(n_sites: int = N_SITES, noise="sigma3", mean_level: float = 100.0,
                          n_iter: int = 20000, seed: int = 0, noise_scale: float = 1.0) -> dict:
    """MSEs of the identity, the Hadamard S-code and the searched SNR-optimal matrix.

    Returns a dict with ``mse`` (identity, s_matrix, snr_optimal: searched from the
    identity as in the paper, snr_optimal_from_both: searched from the identity and from
    the S-code), ``gain_vs_identity``
    (identity MSE / MSE), the S-code used, the searched W and the theoretical S-code gain
    for signal-independent noise, (n + 1)^2 / (4 n).
    """
    sigma_p2, sigma_r2 = noise_coefficients(noise)
    searches = {
        start: SnrOptimalMultiplexer(n_sites=n_sites, noise=(sigma_p2, sigma_r2), n_iter=n_iter,
                                     seed=seed, noise_scale=noise_scale, start=start).fit(mean_level)
        for start in ("identity", "both")
    }
    search = searches["identity"]
    S = s_matrix_for_sites(n_sites)
    mse = {
        "identity": multiplexing_mse(np.eye(n_sites), sigma_p2, sigma_r2, mean_level, noise_scale),
        "s_matrix": multiplexing_mse(S, sigma_p2, sigma_r2, mean_level, noise_scale),
        "snr_optimal": search.mse_,
        "snr_optimal_from_both": searches["both"].mse_,
    }
    order = int(S[:, 0].sum() * 2 - 1) if n_sites > 1 else 1
    return {
        "n_sites": n_sites,
        "sigma_p2": sigma_p2,
        "sigma_r2": sigma_r2,
        "mean_level": mean_level,
        "mse": mse,
        "gain_vs_identity": {k: mse["identity"] / v for k, v in mse.items()},
        "s_matrix_order": order,
        "s_matrix_theory_gain": (order + 1) ** 2 / (4 * order),
        "s_matrix": S,
        "snr_optimal_W": search.W_,
        "snr_optimal_from_both_W": searches["both"].W_,
    }


def main(argv=None) -> int:
    """Print the MSE comparison: python -m mux_trainer.snr_optimal [--noise sigma3] [--mean-level 50]."""
    import argparse

    parser = argparse.ArgumentParser(description="SNR-optimal search vs Hadamard S-code (MSE)")
    parser.add_argument("--noise", default="sigma3", help="sigma1|sigma2|sigma3 or SP2,SR2")
    parser.add_argument("--mean-level", type=float, nargs="+", default=[10.0, 50.0, 200.0],
                        help="mean gray level(s) of a one-site image")
    parser.add_argument("--sites", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    noise = tuple(float(v) for v in args.noise.split(",")) if "," in args.noise else args.noise
    print(f"noise {args.noise}, {args.sites} sites, {args.iterations} iterations, seed {args.seed}")
    print("MSE gain over the identity (identity MSE / MSE; higher is better)")
    print(f"{'mean level':>10} {'S-code':>8} {'SNR-opt (paper)':>16} {'SNR-opt (both)':>15}  lit sites per image (paper)")
    for level in args.mean_level:
        r = compare_with_hadamard(args.sites, noise, level, args.iterations, args.seed)
        g = r["gain_vs_identity"]
        lit = r["snr_optimal_W"].sum(axis=0).astype(int).tolist()
        print(f"{level:>10.1f} {g['s_matrix']:>8.3f} {g['snr_optimal']:>16.3f} "
              f"{g['snr_optimal_from_both']:>15.3f}  {lit}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
