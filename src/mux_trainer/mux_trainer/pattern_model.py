"""What every trained method shares: patterns, a classifier per column count, prediction.

Greedy, SNR-optimal and naive models all end as a pattern matrix plus one fitted
`MuxClassifier` per number of columns; this mixin holds the code for training those
classifiers on rendered data, predicting rendered images and writing the artifact.
"""
from __future__ import annotations

import numpy as np
from joblib import Parallel, delayed
from lightstage_physics.rig import N_CHANNELS
from mux_classifier.artifact import TrainedArtifact
from mux_classifier.estimator import MuxClassifier

from .column_count import choose_column_count
from .data import noise_dict, search_data
from .evaluation import CandidateEvaluator, images_per_column
from .rendering import SearchData
from .search_params import (Execution, FinalClassifier, GroupedParamsMixin, Rendering,
                            SplitScoring, check_group)


def _fit(classifier, X, y):
    return classifier.fit_features(X, y)


class PatternModelMixin(GroupedParamsMixin):
    """Needs `mode`, `seed`, `count_rule` and the setting groups (`search_params`) `scoring`,
    `rendering`, `final_classifier`, `execution`; after fit: `patterns_`, `classifiers_`,
    `accuracy_by_images_`, `class_names_`, `evaluator_`, `inner_estimate_` and
    `noise_` (the noise setting the fit rendered with, as an artifact stores it)."""

    method_name = 'patterns'
    # the split classifier when `scoring.classifier` is None: one matrix per image count is
    # scored exactly (the greedy search screens with ridge instead)
    default_split_classifier = 'squared_hinge'

    @property
    def images_per_pattern(self) -> int:
        return images_per_column(self.mode, N_CHANNELS)

    def _check_groups(self) -> None:
        """TypeError / ValueError for a setting group of the wrong type or out of range."""
        for name, kind in (('scoring', SplitScoring), ('rendering', Rendering),
                           ('final_classifier', FinalClassifier), ('execution', Execution)):
            check_group(self, name, kind)

    @property
    def split_classifier(self) -> str:
        """The classifier of the split accuracies: `scoring.classifier`, or the method's."""
        return self.scoring.classifier or self.default_split_classifier

    def _evaluator(self, data: SearchData, n_jobs: int = 1,
                   chunk_size: int = 32) -> CandidateEvaluator:
        """The candidate evaluator scoring as `scoring` says, seeded by `seed`."""
        s = self.scoring
        return CandidateEvaluator(data, mode=self.mode, n_repeats=s.n_repeats,
                                  test_fraction=s.test_fraction,
                                  inner_classifier=self.split_classifier, alpha=s.alpha, C=s.C,
                                  seed=self.seed, n_jobs=n_jobs, chunk_size=chunk_size,
                                  inner_groups=s.inner_groups)

    def _data(self, X) -> SearchData:
        """The search's data: X itself, or a ModelSet rendered as `rendering` says (noise,
        HOG configuration, dimmer, feature extractor). Records its noise setting as
        `noise_` (a SearchData carries its own)."""
        r = self.rendering
        data = X if isinstance(X, SearchData) else search_data(
            X, r.noise, hog_config=r.hog_config, dimmer=r.dimmer, features=r.features)
        self.noise_ = noise_dict(data.noise_name, data.noise_model)
        return data

    def _make_classifier(self, data: SearchData) -> MuxClassifier:
        final = self.final_classifier
        return MuxClassifier(estimator=final.estimator, C=final.C,
                             alpha=final.alpha, hog_config=data.hog_config,
                             random_state=int(self.seed), features=data.features)

    def _fit_classifiers(self, ev, columns) -> dict:
        """One classifier per column count, on the images the search rendered for it.

        The fits (LinearSVC on up to 8 x 4 x 900 HOG values: seconds each) run through joblib.
        """
        counts = list(range(1, columns.shape[1] + 1))
        clfs = Parallel(n_jobs=self.execution.n_jobs)(
            delayed(_fit)(self._make_classifier(ev.data),
                          ev.features(columns[:, :k]), ev.data.labels)
            for k in counts)
        return dict(zip(counts, clfs))

    def _best_count(self) -> int:
        """The column count kept by the estimator's `count_rule` (`column_count`)."""
        return choose_column_count(self.accuracy_by_images_,
                                   getattr(self, 'split_accuracy_by_images_', None),
                                   rule=self.count_rule,
                                   test_fraction=float(self.scoring.test_fraction))

    @property
    def inner_estimate_(self) -> dict:
        """The inner estimate of the kept column count and how it was made: {'accuracy',
        'n_images' (columns), plus `splits.inner_splits`' description (held out by physical
        sample or by pose, groups per class, repeats)}."""
        k = int(self.best_n_patterns_)
        return {'accuracy': float(self.estimate_by_images_[k]), 'n_images': k,
                'search_accuracy': float(self.accuracy_by_images_[k]),
                'selection_optimism': float(self._optimism().get(k, 0.0)),
                **self.evaluator_.inner_}

    def _optimism(self) -> dict:
        return getattr(self, 'optimism_by_images_', None) or {}

    @property
    def estimate_by_images_(self) -> dict:
        """{column count: inner estimate}: the search's split accuracy less the optimism of
        having chosen the columns (greedy) or the candidate light (learned) on these same
        splits (`optimism_by_images_`, `selection_bias`; none for a fixed matrix)."""
        optimism = self._optimism()
        return {k: float(a - optimism.get(k, 0.0)) for k, a in self.accuracy_by_images_.items()}

    def predict_features(self, X: np.ndarray, n_patterns: int) -> np.ndarray:
        """Class indices from features of the first `n_patterns` columns' images."""
        clf = self.classifiers_[int(n_patterns)]
        return clf.predict_features(X[:, :clf.n_features_in_])

    def to_artifact(self, n_patterns: int | None = None, provenance: dict | None = None) -> TrainedArtifact:
        """The trained artifact (patterns + classifier per image count) for the classify node.

        n_patterns: keep the first n columns (default: all). The artifact records the dimmer
        the training rendered with (`rendering.dimmer`).
        """
        k = self.patterns_.shape[1] if n_patterns is None else int(n_patterns)
        clfs = [self.classifiers_[i] for i in range(1, k + 1)]
        prov = {'method': self.method_name, 'mode': self.mode, 'seed': int(self.seed),
                'n_repeats': int(self.scoring.n_repeats),
                'accuracy_by_patterns': {str(i): float(self.accuracy_by_images_[i])
                                         for i in range(1, k + 1)},
                'best_n_patterns': int(self.best_n_patterns_),
                'count_rule': str(self.count_rule),
                'inner_estimate': self.inner_estimate_}
        prov.update(provenance or {})
        noise = self.noise_
        if self.mode == 'per_colour':
            return TrainedArtifact.from_classifiers(
                clfs, site_patterns=self.patterns_[:, :k], class_names=self.class_names_,
                noise=noise, provenance=prov, dimmer=self.rendering.dimmer)
        return TrainedArtifact.from_classifiers(
            clfs, led_patterns=self.patterns_[:, :k], mode='naive' if self.method_name == 'naive' else 'joint',
            class_names=self.class_names_, noise=noise, provenance=prov,
            dimmer=self.rendering.dimmer)
