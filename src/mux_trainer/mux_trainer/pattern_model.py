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
from .evaluation import images_per_column
from .rendering import SearchData


def _fit(classifier, X, y):
    return classifier.fit_features(X, y)


class PatternModelMixin:
    """Needs `mode`, `seed`, `noise`, `hog_config`, `dimmer`, `features`, `final_classifier`,
    `final_C`, `final_alpha`; after fit:
    `patterns_`, `classifiers_`, `accuracy_by_images_`, `class_names_`, `evaluator_` and
    `noise_` (the noise setting the fit rendered with, as an artifact stores it)."""

    method_name = 'patterns'

    @property
    def images_per_pattern(self) -> int:
        return images_per_column(self.mode, N_CHANNELS)

    def _data(self, X) -> SearchData:
        """The search's data: X itself, or a ModelSet rendered with the estimator's noise,
        HOG configuration, dimmer and feature extractor. Records its noise setting as
        `noise_` (a SearchData carries its own)."""
        data = X if isinstance(X, SearchData) else search_data(
            X, self.noise, hog_config=self.hog_config, dimmer=self.dimmer,
            features=self.features)
        self.noise_ = noise_dict(data.noise_name, data.noise_model)
        return data

    def _make_classifier(self, data: SearchData) -> MuxClassifier:
        return MuxClassifier(estimator=self.final_classifier, C=self.final_C,
                             alpha=self.final_alpha, hog_config=data.hog_config,
                             random_state=int(self.seed), features=data.features)

    def _fit_classifiers(self, ev, columns) -> dict:
        """One classifier per column count, on the images the search rendered for it.

        The fits (LinearSVC on up to 8 x 4 x 900 HOG values: seconds each) run through joblib.
        """
        counts = list(range(1, columns.shape[1] + 1))
        clfs = Parallel(n_jobs=getattr(self, 'n_jobs', 1))(
            delayed(_fit)(self._make_classifier(ev.data),
                          ev.features(columns[:, :k]), ev.data.labels)
            for k in counts)
        return dict(zip(counts, clfs))

    def _best_count(self) -> int:
        """The column count kept by the estimator's `count_rule` (`column_count`)."""
        return choose_column_count(self.accuracy_by_images_,
                                   getattr(self, 'split_accuracy_by_images_', None),
                                   rule=getattr(self, 'count_rule', 'max'),
                                   test_fraction=float(self.test_fraction))

    def predict_features(self, X: np.ndarray, n_patterns: int) -> np.ndarray:
        """Class indices from features of the first `n_patterns` columns' images."""
        clf = self.classifiers_[int(n_patterns)]
        return clf.predict_features(X[:, :clf.n_features_in_])

    def to_artifact(self, n_patterns: int | None = None, provenance: dict | None = None) -> TrainedArtifact:
        """The trained artifact (patterns + classifier per image count) for the classify node.

        n_patterns: keep the first n columns (default: all). The artifact records the dimmer
        the training rendered with (the estimator's `dimmer`).
        """
        k = self.patterns_.shape[1] if n_patterns is None else int(n_patterns)
        clfs = [self.classifiers_[i] for i in range(1, k + 1)]
        prov = {'method': self.method_name, 'mode': self.mode, 'seed': int(self.seed),
                'n_repeats': int(self.n_repeats),
                'accuracy_by_patterns': {str(i): float(self.accuracy_by_images_[i])
                                         for i in range(1, k + 1)},
                'best_n_patterns': int(self.best_n_patterns_),
                'count_rule': str(getattr(self, 'count_rule', 'max'))}
        prov.update(provenance or {})
        noise = self.noise_
        if self.mode == 'per_colour':
            return TrainedArtifact.from_classifiers(
                clfs, site_patterns=self.patterns_[:, :k], class_names=self.class_names_,
                noise=noise, provenance=prov, dimmer=self.dimmer)
        return TrainedArtifact.from_classifiers(
            clfs, led_patterns=self.patterns_[:, :k], mode='naive' if self.method_name == 'naive' else 'joint',
            class_names=self.class_names_, noise=noise, provenance=prov, dimmer=self.dimmer)
