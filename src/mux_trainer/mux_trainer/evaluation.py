"""Candidate evaluation: how good is the illumination matrix `[columns so far | candidate]`?

For one new column the whole training set is rendered under the earlier columns and each
candidate with fresh noise, features are extracted (the data's extractor, the HOG grid by
default; `rendering.scoring_features`), and the mean test accuracy over
`n_repeats` inner splits is the candidate's score: each holds out whole physical samples
(a quarter of every class's, all their poses) where the data has two or more of every class,
else a quarter of the pose indices, the same for every class (`splits.inner_splits`,
`SplitScoring.inner_groups`). Everything is seeded: the same seed gives the same scores whatever
`n_jobs` or joblib backend is used.

Random numbers (common random numbers within a column):
- the splits are drawn once per search from `seed` and shared by every candidate and column;
- for column j, the earlier columns' images get one fresh noise draw and every candidate's
  images share one noise draw (`SeedSequence([seed, j, 1])` and `[seed, j, 0]`). Candidates
  of a column are thus compared on identical noise (a paired comparison, far less variance
  between them) and the images are still re-rendered with new noise at every column.

Speed: candidates are scored in chunks dispatched with joblib (any backend, e.g.
`joblib.parallel_backend("dask")`), or, inside `cluster.dask_cluster(address)`, on that Dask
cluster with the data and the column's context broadcast to each worker once; within a chunk they are visited in Gray-code order so
each render is the previous one plus or minus one site image; the earlier columns enter only
through the kernel `K_prev = X_prev X_prev^T`, computed once per column.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
from joblib import Parallel, delayed, effective_n_jobs
from threadpoolctl import threadpool_limits

from .cluster import ArraySized, active_cluster
from .rendering import (SearchData, add_noise, clean_led_images, clean_site_images,
                        image_features, scoring_features, standard_normal, standardise_columns)
from .split_scoring import make_scorer
from .selection_bias import split_groups
from .splits import inner_splits

MODES = ('per_colour', 'joint')


def images_per_column(mode: str, n_channels: int = 4) -> int:
    """Images one pattern column yields: 4 (R, G, B, NIR) per colour, 1 in the joint mode."""
    if mode == 'per_colour':
        return n_channels
    if mode == 'joint':
        return 1
    raise ValueError(f'unknown mode {mode!r}; use one of {MODES}')


def render(data: SearchData, mode: str, patterns: np.ndarray) -> np.ndarray:
    """Noise-free images `(n_images, n, pixels)` of a pattern matrix in the given mode."""
    if mode == 'per_colour':
        return clean_site_images(data, patterns)
    if mode == 'joint':
        return clean_led_images(data, patterns)
    raise ValueError(f'unknown mode {mode!r}; use one of {MODES}')


def column_rng(seed: int, column: int, stream: int) -> np.random.Generator:
    """The generator of one column's noise; stream 0 = candidates, 1 = earlier columns."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(column), int(stream)]))


@dataclass
class ColumnContext(ArraySized):
    """What a worker needs to score candidates for one new column (picklable)."""

    mode: str
    column: int
    z: np.ndarray | None           # (images_per_column, n, pixels) float32 candidate noise
    X_prev: np.ndarray | None      # (n, features of earlier columns) float32
    K_prev: np.ndarray             # (n, n) float64 kernel of the earlier columns
    test_masks: list
    scorer: object
    n_classes: int


def _score_features(data: SearchData, ctx: ColumnContext, Xc: np.ndarray) -> np.ndarray:
    if ctx.scorer.needs_features:
        X = Xc if ctx.X_prev is None else np.hstack([ctx.X_prev, Xc])
        return ctx.scorer.split_accuracies(data.labels, ctx.test_masks, X=X, n_classes=ctx.n_classes)
    K = ctx.K_prev + (Xc @ Xc.T).astype(np.float64)
    return ctx.scorer.split_accuracies(data.labels, ctx.test_masks, K=K, n_classes=ctx.n_classes)


def score_candidate_chunk(data: SearchData, ctx: ColumnContext, candidates: np.ndarray,
                          timings: dict | None = None) -> np.ndarray:
    """Split accuracies `(n_candidates, n_splits)` of a chunk of candidate columns.

    Per-colour candidates are rendered incrementally: each is the previous candidate's
    images plus/minus the site images in which the two differ (one, in Gray-code order).
    timings: if a dict, seconds spent in 'render', 'noise', 'features', 'classifier' are
    added to it (for benchmarks).
    """
    # one BLAS thread per worker: the matrices are small, and threaded BLAS on a busy
    # 2-core machine was measured 5x slower here; parallelism comes from joblib workers
    with threadpool_limits(limits=1, user_api='blas'):
        return _score_chunk(data, ctx, np.asarray(candidates, dtype=np.float32), timings)


def score_chunk_with(data: SearchData, ctx: ColumnContext, candidates: np.ndarray,
                     scorer=None) -> np.ndarray:
    """`score_candidate_chunk` with another split scorer than the context's (a cluster task:
    the context is broadcast once per column, the scorer travels with the task)."""
    if scorer is not None:
        ctx = dataclasses.replace(ctx, scorer=scorer)
    return score_candidate_chunk(data, ctx, candidates)


def _score_chunk(data, ctx, candidates, timings):
    out = np.empty((candidates.shape[1], len(ctx.test_masks)))
    noisy = None
    clean = None
    clock = time.perf_counter
    spent = dict.fromkeys(('render', 'noise', 'features', 'classifier'), 0.0)
    for j in range(candidates.shape[1]):
        t0 = clock()
        if ctx.mode == 'per_colour':
            w = candidates[:, j]
            if clean is None:
                clean = clean_site_images(data, w[:, None])
            else:
                diff = w - candidates[:, j - 1]
                for site in np.flatnonzero(diff):
                    if diff[site] == 1:
                        clean += data.basis[site]
                    else:
                        clean += np.float32(diff[site]) * data.basis[site]
        else:
            clean = clean_led_images(data, candidates[:, j:j + 1])
        t1 = clock()
        noisy = add_noise(data, clean, ctx.z, out=noisy)
        t2 = clock()
        Xc = scoring_features(data, noisy)
        t3 = clock()
        out[j] = _score_features(data, ctx, Xc)
        t4 = clock()
        spent['render'] += t1 - t0
        spent['noise'] += t2 - t1
        spent['features'] += t3 - t2
        spent['classifier'] += t4 - t3
    if timings is not None:
        for key, value in spent.items():
            timings[key] = timings.get(key, 0.0) + value
    return out


class CandidateEvaluator:
    """Scores candidate columns given the columns chosen so far (see module docstring).

    Parameters
    ----------
    data : SearchData
    mode : 'per_colour' (8-site patterns, 4 images each) or 'joint' (32-LED patterns).
    n_repeats : random inner splits per candidate (the paper: 400).
    test_fraction : share of the physical samples (or pose indices) held out per split (the
        paper: 0.25).
    inner_classifier : 'ridge' (kernel shared by all splits; fast), 'squared_hinge' (the exact
        linear SVM in kernel form) or 'linear_svm' (one LinearSVC per split, slowest). See
        `split_scoring`; timings in docs/SEARCH.md.
    alpha, C : ridge penalty / the linear SVM's C.
    inner_groups : 'auto' | 'poses' | 'instances': what the splits hold out
        (`splits.inner_splits`; `SplitScoring.inner_groups`); `inner_` describes them.
    seed : seeds splits and noise.
    n_jobs : joblib workers; chunk_size : candidates per task (fixed, so that results do not
        depend on n_jobs).
    """

    def __init__(self, data: SearchData, mode: str = 'per_colour', n_repeats: int = 400,
                 test_fraction: float = 0.25, inner_classifier: str = 'ridge',
                 alpha: float = 0.5, C: float = 1.0, seed: int = 0, n_jobs: int = 1,
                 chunk_size: int = 32, inner_groups: str = 'auto'):
        images_per_column(mode)
        self.data = data
        self.mode = mode
        self.n_repeats = n_repeats
        self.test_fraction = test_fraction
        self.inner_classifier = inner_classifier
        self.seed = int(seed)
        self.n_jobs = n_jobs
        self.chunk_size = chunk_size
        params = {'alpha': alpha} if inner_classifier == 'ridge' else {'C': C}
        self.scorer = make_scorer(inner_classifier, **params)
        self.test_masks, self.inner_ = inner_splits(
            data.labels, data.pose_index, data.instance, n_repeats, test_fraction,
            np.random.default_rng([self.seed, 2 ** 31]), inner_groups)
        self.split_groups = split_groups(self.test_masks)
        self.n_classes = len(data.class_names)

    @property
    def images_per_column(self) -> int:
        return images_per_column(self.mode, self.data.n_channels)

    def noisy_images(self, columns: np.ndarray, column: int) -> np.ndarray:
        """Noisy images of `columns` as rendered when column index `column` is searched."""
        clean = render(self.data, self.mode, columns)
        z = standard_normal(column_rng(self.seed, column, 1), clean.shape)
        return add_noise(self.data, clean, z)

    def candidate_noise(self, column: int) -> np.ndarray | None:
        if self.data.noise_a == 0 and self.data.noise_b == 0:
            return None
        shape = (self.images_per_column, self.data.n_samples, self.data.basis.shape[3])
        return standard_normal(column_rng(self.seed, column, 0), shape)

    def prepare_column(self, columns: np.ndarray | None) -> ColumnContext:
        """Render the earlier columns with this column's fresh noise; their features/kernel."""
        column = 0 if columns is None else columns.shape[1]
        n = self.data.n_samples
        X_prev = None
        K_prev = np.zeros((n, n))
        if column > 0:
            X_prev = scoring_features(self.data, self.noisy_images(columns, column))
            X64 = X_prev.astype(np.float64)
            K_prev = X64 @ X64.T
        return ColumnContext(mode=self.mode, column=column, z=self.candidate_noise(column),
                             X_prev=X_prev if self.scorer.needs_features else None,
                             K_prev=K_prev, test_masks=self.test_masks, scorer=self.scorer,
                             n_classes=self.n_classes)

    def score(self, ctx: ColumnContext, candidates: np.ndarray,
              parallel: Parallel | None = None, scorer=None,
              chunk_size: int | None = None, on_progress=None) -> np.ndarray:
        """Split accuracies `(n_candidates, n_splits)` for candidate columns `(rows, c)`.

        scorer: another split scorer than the evaluator's (it must work from the kernel, as
        `ColumnContext` carries no earlier features for it); chunk_size: candidates per task
        instead of the evaluator's (fixed by the caller, so results do not depend on n_jobs).
        on_progress(candidates scored so far): called before each round of tasks (one task
        per worker, on a Dask cluster once); an exception it raises stops the scoring there
        (a cancel). The tasks are the same either way, so the scores are too.
        """
        candidates = np.asarray(candidates, dtype=np.float32)
        if scorer is not None and scorer.needs_features and ctx.X_prev is None and ctx.column > 0:
            raise ValueError(f'{type(scorer).__name__} needs features; this column context '
                             'holds only the kernel of the earlier columns')
        size = self.chunk_size if chunk_size is None else int(chunk_size)
        chunks = [candidates[:, b:b + size] for b in range(0, candidates.shape[1], size)]
        cluster = active_cluster()
        if cluster is not None:  # the same tasks on a Dask cluster (cluster.py); --jobs unused
            if on_progress is not None:
                on_progress(0)
            parts = cluster.map(score_chunk_with, {'search data': self.data, 'column context': ctx},
                                chunks, scorer=scorer)
        else:
            if parallel is None:
                parallel = Parallel(n_jobs=self.n_jobs)
            per_round = len(chunks) if on_progress is None else effective_n_jobs(parallel.n_jobs)
            parts = []
            for r in range(0, len(chunks), per_round):
                if on_progress is not None:
                    on_progress(r * size)
                parts += parallel(delayed(score_chunk_with)(self.data, ctx, chunk, scorer)
                                  for chunk in chunks[r:r + per_round])
        return np.vstack(parts) if parts else np.empty((0, len(self.test_masks)))

    def score_features(self, X: np.ndarray) -> np.ndarray:
        """Split accuracies `(n_splits,)` of features X (n, F) of a whole stack, z-scored over
        the samples (`standardise_columns`): for features that are not each image's alone
        (cross-image statistics), which `score`'s column-by-column kernel cannot add up."""
        X = standardise_columns(X)
        if self.scorer.needs_features:
            return self.scorer.split_accuracies(self.data.labels, self.test_masks, X=X,
                                                n_classes=self.n_classes)
        X64 = X.astype(np.float64)
        return self.scorer.split_accuracies(self.data.labels, self.test_masks, K=X64 @ X64.T,
                                            n_classes=self.n_classes)

    def images(self, columns: np.ndarray, column_noise_of: int | None = None) -> np.ndarray:
        """Noisy images `(n_images, n, pixels)` of all `columns` with the noise the search
        used for its last column (the earlier columns' noise of that step, the candidate
        noise for the last)."""
        k = columns.shape[1]
        last = k - 1 if column_noise_of is None else column_noise_of
        clean = render(self.data, self.mode, columns[:, -1:])
        last_images = add_noise(self.data, clean, self.candidate_noise(last))
        if k == 1:
            return last_images
        return np.concatenate([self.noisy_images(columns[:, :-1], last), last_images])

    def features(self, columns: np.ndarray, column_noise_of: int | None = None) -> np.ndarray:
        """Raw features of all images of `columns` (a classifier scales its own), `images`."""
        return image_features(self.data, self.images(columns, column_noise_of))
