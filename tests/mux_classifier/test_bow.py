"""Bag of visual words: codebook, encoding and estimator conventions."""
import numpy as np
import pytest
from sklearn.base import clone
from sklearn.cluster import MiniBatchKMeans
from sklearn.pipeline import make_pipeline
from sklearn.svm import LinearSVC

from mux_classifier.bow import BagOfVisualWords
from mux_classifier.hog import HogConfig, hog_batch


def textures(n_per_class=6, seed=0):
    """Two classes of 120 x 120 images with the same mean and contrast: stripes vs blobs."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:120, :120].astype(np.float32)
    images, labels = [], []
    for i in range(n_per_class):
        phase = rng.uniform(0, 2 * np.pi)
        images.append(np.sin(xx / 3.0 + phase) * 300 + 500)
        labels.append(0)
        images.append(np.sin(xx / 3.0 + phase) * np.sin(yy / 3.0) * 300 + 500)
        labels.append(1)
    images = np.stack(images) + rng.normal(0, 30, (len(images), 120, 120))
    return images.astype(np.float32), np.array(labels)


def test_descriptors_are_hog_blocks():
    images, _ = textures(1)
    bow = BagOfVisualWords(n_words=4)
    desc = bow.local_descriptors(images)
    assert desc.shape == (2, 14 * 14, 36)
    ref = hog_batch(images, HogConfig(image_size=120, cell_px=8, block_cells=2))
    np.testing.assert_array_equal(desc.reshape(2, -1), ref)


def test_histograms_count_nearest_words():
    images, _ = textures(4)
    bow = BagOfVisualWords(n_words=8, random_state=1).fit(images)
    assert bow.codebook_.shape == (8, 36)
    hist = bow.transform(images)
    assert hist.shape == (8, 8) and hist.dtype == np.float32
    np.testing.assert_allclose(hist.sum(axis=1), 1.0, rtol=1e-6)
    # the same counts by hand: nearest codebook entry of each descriptor
    desc = bow.local_descriptors(images[:1])[0]
    d2 = ((desc[:, None, :] - bow.codebook_[None]) ** 2).sum(axis=2)
    expected = np.bincount(d2.argmin(axis=1), minlength=8) / desc.shape[0]
    np.testing.assert_allclose(hist[0], expected, atol=1e-6)


def test_stacks_concatenate_per_image_histograms():
    images, _ = textures(3)
    bow = BagOfVisualWords(n_words=5).fit(images)
    stacks = np.stack([images[:3], images[3:]], axis=1)   # (3, 2, H, W)
    got = bow.transform(stacks)
    assert got.shape == (3, 10)
    np.testing.assert_array_equal(got[:, :5], bow.transform(images[:3]))
    np.testing.assert_array_equal(got[:, 5:], bow.transform(images[3:]))


def test_separates_textures_in_a_pipeline():
    train, y_train = textures(6, seed=0)
    test, y_test = textures(4, seed=1)
    model = make_pipeline(BagOfVisualWords(n_words=16), LinearSVC(C=10.0, max_iter=10000))
    assert model.fit(train, y_train).score(test, y_test) == 1.0


def test_reproducible_and_clonable():
    images, _ = textures(3)
    a = BagOfVisualWords(n_words=6, random_state=3, norm="hellinger").fit(images)
    b = clone(a).fit(images)
    np.testing.assert_array_equal(a.codebook_, b.codebook_)
    assert isinstance(a.kmeans_, MiniBatchKMeans)
    np.testing.assert_allclose((a.transform(images) ** 2).sum(axis=1), 1.0, rtol=1e-5)


def test_errors():
    images, _ = textures(1)
    with pytest.raises(ValueError, match="more training images or lower n_words"):
        BagOfVisualWords(n_words=1000).fit(images)
    with pytest.raises(ValueError, match="norm"):
        BagOfVisualWords(norm="max").fit(images)
    with pytest.raises(ValueError, match=r"\(n, H, W\)"):
        BagOfVisualWords().fit(images[0])
