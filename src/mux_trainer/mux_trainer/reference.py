"""The straightforward implementation of the paper's candidate evaluation (slow, for checks).

One image at a time: `L @ w` per sample and colour, float64 noise, `skimage.feature.hog`
per image, and a classifier fitted per split (LinearSVC as in the paper, or sklearn's Ridge
on +-1 targets with a bias feature, the explicit form of `split_scoring.RidgeSplitScorer`).
It consumes the same random numbers as the fast path (`evaluation.column_rng`, the same
splits), so the two must agree; the tests and benchmarks/bench_search.py compare them.
"""
from __future__ import annotations

import numpy as np
from skimage.feature import hog
from sklearn.linear_model import Ridge
from sklearn.svm import LinearSVC

from .evaluation import column_rng, images_per_column
from .rendering import SearchData
from .splits import pose_splits


def reference_splits(data: SearchData, n_repeats: int, test_fraction: float, seed: int):
    """The splits the fast evaluator draws for this seed."""
    return pose_splits(data.pose_index, n_repeats, test_fraction,
                       np.random.default_rng([int(seed), 2 ** 31]))


def reference_images(data: SearchData, mode: str, columns: np.ndarray, z: np.ndarray | None):
    """Noisy images `(n, n_images, H, W)` rendered one sample and image at a time."""
    n, (H, W) = data.n_samples, data.image_shape
    per = images_per_column(mode, data.n_channels)
    n_img = per * columns.shape[1]
    out = np.empty((n, n_img, H, W))
    for i in range(n):
        for j in range(columns.shape[1]):
            for c in range(per):
                if mode == 'per_colour':
                    L = data.basis[:, c, i, :].T.astype(np.float64)          # (pixels, sites)
                    w = columns[:, j].astype(np.float64)
                else:
                    L = data.basis[:, :, i, :].reshape(-1, H * W).T.astype(np.float64)
                    w = columns[:, j].astype(np.float64)
                mean = L @ w
                img = mean
                if z is not None and (data.noise_a or data.noise_b):
                    std = np.sqrt(data.noise_a * np.maximum(mean, 0) + data.noise_b)
                    img = mean + std * z[j * per + c, i].astype(np.float64)
                out[i, j * per + c] = np.clip(img, 0, data.max_level).reshape(H, W)
    return out


def reference_features(data: SearchData, images: np.ndarray) -> np.ndarray:
    cfg = data.hog_config
    n, k = images.shape[:2]
    return np.stack([
        np.concatenate([
            hog(images[i, j].astype(np.float32), orientations=cfg.orientations,
                pixels_per_cell=(cfg.cell_px, cfg.cell_px),
                cells_per_block=(cfg.block_cells, cfg.block_cells), block_norm=cfg.block_norm)
            for j in range(k)])
        for i in range(n)])


def reference_split_accuracies(X, labels, masks, classifier='linear_svm', alpha=0.5, C=1.0):
    labels = np.asarray(labels)
    n_classes = int(labels.max()) + 1
    acc = np.empty(len(masks))
    for r, test in enumerate(masks):
        train = ~test
        if classifier == 'linear_svm':
            clf = LinearSVC(C=C, max_iter=5000).fit(X[train], labels[train])
            pred = clf.predict(X[test])
        elif classifier == 'ridge':
            Xa = np.hstack([X, np.ones((X.shape[0], 1))])
            Y = -np.ones((labels.size, n_classes))
            Y[np.arange(labels.size), labels] = 1
            reg = Ridge(alpha=alpha, fit_intercept=False).fit(Xa[train], Y[train])
            pred = reg.predict(Xa[test]).argmax(axis=1)
        else:
            raise ValueError(f'unknown classifier {classifier!r}')
        acc[r] = np.mean(pred == labels[test])
    return acc


def reference_candidate_scores(data: SearchData, mode: str, columns: np.ndarray | None,
                               candidates: np.ndarray, *, seed: int = 0, n_repeats: int = 400,
                               test_fraction: float = 0.25, classifier: str = 'linear_svm',
                               alpha: float = 0.5, C: float = 1.0, timings: dict | None = None):
    """Split accuracies `(n_candidates, n_repeats)`, the paper's loop written plainly.

    timings: if a dict, receives the seconds spent in 'render_noise', 'features',
    'classifier' (summed over candidates).
    """
    import time
    rows = candidates.shape[0]
    columns = np.zeros((rows, 0), np.float32) if columns is None else np.asarray(columns)
    col = columns.shape[1]
    masks = reference_splits(data, n_repeats, test_fraction, seed)
    per = images_per_column(mode, data.n_channels)
    shape = (per, data.n_samples, data.basis.shape[3])
    z = column_rng(seed, col, 0).standard_normal(shape, dtype=np.float32)
    X_prev = None
    if col:
        zp = column_rng(seed, col, 1).standard_normal((per * col,) + shape[1:], dtype=np.float32)
        X_prev = reference_features(data, reference_images(data, mode, columns, zp))
    t = timings if timings is not None else {}
    for key in ('render_noise', 'features', 'classifier'):
        t.setdefault(key, 0.0)
    out = np.empty((candidates.shape[1], n_repeats))
    for j in range(candidates.shape[1]):
        t0 = time.perf_counter()
        imgs = reference_images(data, mode, candidates[:, j:j + 1], z)
        t1 = time.perf_counter()
        Xc = reference_features(data, imgs)
        X = Xc if X_prev is None else np.hstack([X_prev, Xc])
        t2 = time.perf_counter()
        out[j] = reference_split_accuracies(X, data.labels, masks, classifier, alpha, C)
        t3 = time.perf_counter()
        t['render_noise'] += t1 - t0
        t['features'] += t2 - t1
        t['classifier'] += t3 - t2
    return out
