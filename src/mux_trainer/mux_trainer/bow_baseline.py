"""The naive baseline with a bag of visual words: all LEDs on, one image, BoW + linear SVM.

The codebook (`mux_classifier.bow.BagOfVisualWords`, dense local HOG + k-means) is learnt
from the training renders; each image becomes a histogram of visual words, classified by a
linear SVM (the same family of classifier as every other method). The paper argues a BoW
hurts on visually similar classes because it pools away where features are; this baseline
measures that on our data.
"""
from __future__ import annotations

import numpy as np
from mux_classifier.bow import BagOfVisualWords
from sklearn.base import BaseEstimator
from sklearn.svm import LinearSVC

from .holdout import test_images
from .rendering import SearchData, add_noise
from .evaluation import render


class NaiveBowClassifier(BaseEstimator):
    """BoW histograms of the all-LEDs-on image, then LinearSVC."""

    def __init__(self, n_words=200, norm='hellinger', C=1.0, seed=0):
        self.n_words = n_words
        self.norm = norm
        self.C = C
        self.seed = seed

    def _images(self, data: SearchData, noisy: np.ndarray) -> np.ndarray:
        H, W = data.image_shape
        return noisy.reshape(data.n_samples, H, W)

    def fit_from_naive(self, naive, data: SearchData):
        """Train on the renders the fitted NaiveClassifier `naive` used (same noise draw)."""
        ev = naive.evaluator_
        clean = render(data, 'joint', naive.patterns_)
        images = self._images(data, add_noise(data, clean, ev.candidate_noise(0)))
        self.patterns_ = naive.patterns_
        probe = BagOfVisualWords(image_size=data.image_shape[0])
        n_desc = data.n_samples * probe.local_descriptors(images[:1]).shape[1]
        # small captures have few local descriptors: keep at least 4 per word
        n_words = int(min(self.n_words, max(2, n_desc // 4)))
        self.bow_ = BagOfVisualWords(n_words=n_words, norm=self.norm,
                                     image_size=data.image_shape[0], random_state=self.seed)
        hist = self.bow_.fit_transform(images)
        self.svm_ = LinearSVC(C=self.C, max_iter=10000, random_state=self.seed).fit(hist, data.labels)
        return self

    @property
    def n_words_(self) -> int:
        return int(self.bow_.codebook_.shape[0])

    def predict_images(self, data: SearchData, noisy: np.ndarray) -> np.ndarray:
        return self.svm_.predict(self.bow_.transform(self._images(data, noisy)))

    def predict_test(self, test_data: SearchData, render_index: int, seed: int) -> np.ndarray:
        """Class indices for fresh held-out renders (the same noise draws as the others get)."""
        noisy = test_images(test_data, 'joint', self.patterns_, render_index, seed)
        return self.predict_images(test_data, noisy)
