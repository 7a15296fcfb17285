"""The paper's baselines: fixed pattern matrices with a classifier per image count.

- `FixedPatternClassifier`: any given pattern matrix; for k = 1..m it scores the first k
  columns with the same repeated inner splits as the greedy search (by default with the exact
  linear SVM, the paper's classifier: one matrix per image count needs no fast screen) and
  trains the final classifier on them ("a classifier was trained for each image count using noise-accurate
  rendered imagery").
- `SnrOptimalClassifier`: the matrix from `snr_optimal.SnrOptimalMultiplexer` (stochastic
  bit flips from the identity and from the S-code, `start='identity'` for the paper's search
  alone; cond < 100, lowest demultiplexing MSE) for the data's noise
  setting and mean single-site level; classifiers use its first k columns (the paper's
  shortcut evaluation). With noise 'none' the MSE criterion is undefined and the Hadamard
  S-matrix code (optimal for signal-independent noise) is used instead.
- `NaiveClassifier`: all 32 LEDs on, one image.
"""
from __future__ import annotations

import numpy as np
from joblib import Parallel
from sklearn.base import BaseEstimator

from .candidate_patterns import all_leds_on
from .pattern_model import PatternModelMixin
from .rendering import SearchData
from .search_params import Execution, FinalClassifier, Rendering, SplitScoring
from .snr_optimal import SnrOptimalMultiplexer, s_matrix_for_sites


class FixedPatternClassifier(PatternModelMixin, BaseEstimator):
    """Classifiers for the first k columns of a fixed pattern matrix, k = 1..m.

    Parameters: `patterns` (rows, m), `mode`, and as the greedy search's: `scoring`
    (`search_params.SplitScoring`; its classifier None: the exact linear SVM, as one
    matrix per image count needs no fast screen), `rendering`, `final_classifier`, `seed`,
    `execution` (only its n_jobs is used: the classifiers' fits) and `count_rule`.

    Fitted attributes: `patterns_`, `accuracy_by_images_` (split accuracy per column count),
    `split_accuracy_by_images_`, `best_n_patterns_` (by `count_rule`, as the greedy search's),
    `classifiers_`, `class_names_`.
    """

    method_name = 'fixed'

    def __init__(self, patterns=None, mode='per_colour', scoring=SplitScoring(),
                 rendering=Rendering(), final_classifier=FinalClassifier(), seed=0,
                 execution=Execution(), count_rule='max'):
        self.patterns = patterns
        self.mode = mode
        self.scoring = scoring
        self.rendering = rendering
        self.final_classifier = final_classifier
        self.seed = seed
        self.execution = execution
        self.count_rule = count_rule

    def _patterns_for(self, data: SearchData) -> np.ndarray:
        if self.patterns is None:
            raise ValueError('FixedPatternClassifier needs a pattern matrix (rows, k)')
        return np.asarray(self.patterns, dtype=np.float32)

    def fit(self, X, y=None):
        self._check_groups()
        data = self._data(X)
        P = self._patterns_for(data)
        rows = data.n_sites if self.mode == 'per_colour' else data.n_sites * data.n_channels
        if P.ndim != 2 or P.shape[0] != rows or P.shape[1] < 1:
            raise ValueError(f'{self.mode} patterns must be ({rows}, k >= 1), got shape {P.shape}')
        ev = self._evaluator(data, n_jobs=1)
        self.evaluator_ = ev
        self.class_names_ = list(data.class_names)
        self.accuracy_by_images_ = {}
        self.split_accuracy_by_images_ = {}
        with Parallel(n_jobs=1) as parallel:
            for k in range(1, P.shape[1] + 1):
                ctx = ev.prepare_column(P[:, :k - 1] if k > 1 else None)
                acc = ev.score(ctx, P[:, k - 1:k], parallel)
                self.accuracy_by_images_[k] = float(acc.mean())
                self.split_accuracy_by_images_[k] = acc[0].copy()
        self.patterns_ = P
        self.best_n_patterns_ = self._best_count()
        self.classifiers_ = self._fit_classifiers(ev, P)
        return self


class SnrOptimalClassifier(FixedPatternClassifier):
    """The SNR-optimal baseline (see module docstring); `multiplexer_` is the fitted search."""

    method_name = 'snr_optimal'

    def __init__(self, n_images=None, n_iter=20000, start='both', mode='per_colour',
                 scoring=SplitScoring(), rendering=Rendering(), final_classifier=FinalClassifier(),
                 seed=0, execution=Execution(), count_rule='max'):
        super().__init__(patterns=None, mode=mode, scoring=scoring, rendering=rendering,
                         final_classifier=final_classifier, seed=seed, execution=execution,
                         count_rule=count_rule)
        self.n_images = n_images
        self.n_iter = n_iter
        self.start = start

    def _patterns_for(self, data: SearchData) -> np.ndarray:
        if self.mode != 'per_colour':
            raise ValueError('the SNR-optimal baseline is defined over site patterns: mode per_colour')
        n_sites = data.n_sites
        if data.noise_a == 0 and data.noise_b == 0:
            self.multiplexer_ = None
            W = s_matrix_for_sites(n_sites)
        else:
            # data.noise_a/b already include the downscale factor: pass them as the model
            mean_level = float(np.mean(data.basis, dtype=np.float64))
            self.multiplexer_ = SnrOptimalMultiplexer(
                n_sites=n_sites, noise=(data.noise_a, data.noise_b), n_iter=self.n_iter,
                start=self.start, seed=self.seed).fit(mean_level)
            W = self.multiplexer_.W_
        if self.n_images is not None:
            W = W[:, :int(self.n_images)]
        return W


class NaiveClassifier(FixedPatternClassifier):
    """All LEDs on, one image per sample (the paper's naive baseline, without BoW)."""

    method_name = 'naive'

    def __init__(self, scoring=SplitScoring(), rendering=Rendering(),
                 final_classifier=FinalClassifier(), seed=0, execution=Execution(),
                 count_rule='max'):
        super().__init__(patterns=None, mode='joint', scoring=scoring, rendering=rendering,
                         final_classifier=final_classifier, seed=seed, execution=execution,
                         count_rule=count_rule)

    def _patterns_for(self, data: SearchData) -> np.ndarray:
        return all_leds_on(data.n_sites * data.n_channels)
