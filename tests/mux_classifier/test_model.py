"""MuxClassifier: scikit-learn estimator conventions and correct linear scores."""
import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.svm import LinearSVC

from mux_classifier.estimator import MuxClassifier
from mux_classifier.features import stack_features
from mux_classifier.hog import HogConfig, hog_batch


def test_stack_features_concatenates_in_image_order(toy_stacks):
    stacks, _ = toy_stacks
    X = stack_features(stacks[:5])
    assert X.shape == (5, 3 * 900) and X.dtype == np.float32
    for j in range(3):
        np.testing.assert_array_equal(X[:, j * 900:(j + 1) * 900], hog_batch(stacks[:5, j]))
    # features of the first j images are a prefix
    np.testing.assert_array_equal(stack_features(stacks[:5, :2]), X[:, :1800])


@pytest.mark.parametrize("shape, message", [
    ((3, 120, 120), "pass stacks"),
    ((2, 3, 64, 64), "120 x 120"),
    ((2, 0, 120, 120), "no images"),
])
def test_stack_features_rejects_bad_shapes(shape, message):
    with pytest.raises(ValueError, match=message):
        stack_features(np.zeros(shape, np.float32))


def test_params_and_clone():
    clf = MuxClassifier(estimator="ridge", alpha=0.5, C=2.0, hog_config=HogConfig(batch_size=4))
    params = clf.get_params()
    assert params == {"estimator": "ridge", "C": 2.0, "alpha": 0.5, "max_iter": 10000,
                      "hog_config": HogConfig(batch_size=4), "random_state": 0,
                      "features": "hog_grid"}
    copy = clone(clf)
    assert copy is not clf and copy.get_params() == params
    assert not hasattr(copy, "coef_")
    assert clf.set_params(C=3.0) is clf and clf.C == 3.0


@pytest.mark.parametrize("estimator", ["linear_svm", "ridge"])
def test_fit_returns_self_and_learns(toy_stacks, estimator):
    stacks, y = toy_stacks
    clf = MuxClassifier(estimator=estimator)
    assert clf.fit(stacks[::2], y[::2]) is clf
    assert clf.n_images_ == 3 and clf.coef_.shape == (4, 2700) and clf.intercept_.shape == (4,)
    np.testing.assert_array_equal(clf.classes_, np.arange(4))
    # held-out samples of a learnable problem
    assert clf.score(stacks[1::2], y[1::2]) >= 0.75
    scores = clf.decision_function(stacks[1::2])
    assert scores.shape == (16, 4)
    np.testing.assert_array_equal(clf.predict(stacks[1::2]), clf.classes_[scores.argmax(axis=1)])


def test_linear_svm_scores_equal_sklearn_on_the_same_features(toy_stacks):
    stacks, y = toy_stacks
    X = stack_features(stacks).astype(np.float64)
    ref = LinearSVC(C=0.5, max_iter=10000, random_state=0).fit(X, y)
    clf = MuxClassifier(C=0.5).fit(stacks, y)
    np.testing.assert_allclose(clf.decision_function(stacks), ref.decision_function(X), atol=1e-8)
    np.testing.assert_array_equal(clf.predict(stacks), ref.predict(X))


def test_two_classes_give_two_score_columns(toy_stacks):
    stacks, y = toy_stacks
    keep = y < 2
    labels = np.where(y[keep] == 0, "real", "fake")
    clf = MuxClassifier().fit(stacks[keep], labels)
    scores = clf.decision_function(stacks[keep])
    assert scores.shape == (keep.sum(), 2)
    np.testing.assert_allclose(scores[:, 0], -scores[:, 1])
    ref = LinearSVC(max_iter=10000, random_state=0).fit(stack_features(stacks[keep]).astype(np.float64), labels)
    np.testing.assert_array_equal(clf.predict(stacks[keep]), ref.predict(stack_features(stacks[keep]).astype(np.float64)))


def test_errors(toy_stacks):
    stacks, y = toy_stacks
    with pytest.raises(NotFittedError):
        MuxClassifier().predict(stacks)
    with pytest.raises(ValueError, match="estimator must be one of"):
        MuxClassifier(estimator="svm").fit(stacks, y)
    with pytest.raises(ValueError, match="at least 2 classes"):
        MuxClassifier().fit(stacks[:3], np.zeros(3))
    with pytest.raises(ValueError, match="one label per sample"):
        MuxClassifier().fit(stacks, y[:-1])
    clf = MuxClassifier(estimator="ridge").fit(stacks[:, :2], y)
    with pytest.raises(ValueError, match="expected 2 images per sample, got 3"):
        clf.predict(stacks)


def test_fit_features_equals_fit(toy_stacks):
    stacks, y = toy_stacks
    a = MuxClassifier(estimator="ridge").fit(stacks, y)
    b = MuxClassifier(estimator="ridge").fit_features(stack_features(stacks), y)
    np.testing.assert_allclose(a.coef_, b.coef_)
    assert b.n_images_ == 3


def test_a_standardised_feature_is_scaled_on_training_samples_and_folded_into_the_weights(toy_stacks):
    """MuxClassifier(features="intensity_stats") = StandardScaler + LinearSVC on the raw
    per-image features, with the scaling folded into coef_ / intercept_ (so the artifact
    stores weights for raw features only)."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import LinearSVC

    from mux_classifier.features import make_extractor
    stacks, y = toy_stacks
    clf = MuxClassifier(features="intensity_stats").fit(stacks, y)
    X = make_extractor("intensity_stats").raw_features(stacks).astype(np.float64)
    assert clf.coef_.shape == (len(np.unique(y)), X.shape[1])
    reference = make_pipeline(StandardScaler(), LinearSVC(C=1.0, max_iter=10000, random_state=0))
    reference.fit(X, y)
    np.testing.assert_array_equal(clf.predict(stacks), reference.predict(X))
    ours = clf.decision_function(stacks)
    theirs = reference.decision_function(X)
    if theirs.ndim == 1:
        theirs = np.stack([-theirs, theirs], axis=1)
    np.testing.assert_allclose(ours, theirs, rtol=1e-6, atol=1e-6 * np.abs(theirs).max())
