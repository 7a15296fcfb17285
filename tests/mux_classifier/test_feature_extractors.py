"""Feature extractors by name: the default is the paper's HOG grid, every extractor keeps the
per-image layout, learned state comes from training stacks only, and the pose-robust ones
do not move when the object does."""
import numpy as np
import pytest

from mux_classifier.features import (DEFAULT_EXTRACTOR, EXTRACTORS, extractor,
                                     features_for_split, stack_features)
from mux_classifier.intensity_stats import intensity_stats
from mux_classifier.object_mask import mask_moments, stack_masks
from mux_classifier.pooled_hog import pooled_hog

LEARNED = [name for name in EXTRACTORS if name not in ("hog_grid", "pose_hog")]


def _objects(n=6, k=3, seed=0, angle_deg=0.0):
    """Stacks of a bright textured bar (object) on a dark noisy floor, 120 x 120."""
    rng = np.random.default_rng(seed)
    stacks = rng.normal(40, 4, (n, k, 120, 120)).astype(np.float32)
    for i in range(n):
        for j in range(k):
            bar = np.zeros((120, 120), np.float32)
            bar[50:70, 25:95] = 300 + 60 * j + 40 * i + rng.normal(0, 30, (20, 70))
            bar[55:65, 40:50] += 150  # a feature off the bar's centre
            stacks[i, j] += np.rot90(bar, int(angle_deg // 90)) if angle_deg else bar
    return stacks


def test_default_is_the_paper_hog_grid_with_unchanged_numbers(toy_stacks):
    stacks, _ = toy_stacks
    assert DEFAULT_EXTRACTOR == "hog_grid"
    ex = extractor()
    out = ex.fit(stacks[:8]).transform(stacks)
    np.testing.assert_array_equal(out, stack_features(stacks))
    assert ex.features_per_image == 900


def test_unknown_name_lists_the_choices():
    with pytest.raises(ValueError, match="hog_grid"):
        extractor("sift")


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_layout_is_per_image_and_prefix(name):
    stacks = _objects(n=8, k=3)
    ex = extractor(name, **({"n_words": 16} if name == "bow" else {}))
    with pytest.raises(ValueError, match="not fitted"):
        ex.transform(stacks)
    full = ex.fit(stacks).transform(stacks)
    d = ex.features_per_image
    assert full.dtype == np.float32 and full.shape == (8, 3 * d)
    assert np.isfinite(full).all()
    # the first j images' features are a prefix: the search slices, never recomputes
    np.testing.assert_allclose(ex.transform(stacks[:, :2]), full[:, :2 * d], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", LEARNED)
def test_fit_never_sees_a_test_pose(name):
    """Train features must not depend on the held-out stacks: corrupting every held-out
    stack would change them if the held-out poses leaked into what fit learns."""
    stacks = _objects(n=10, k=2)
    train, test = np.arange(7), np.arange(7, 10)
    params = {"n_words": 16} if name == "bow" else {}
    X_train, X_test, ex = features_for_split(name, stacks, train, test, **params)
    wild = stacks.copy()
    wild[test] = wild[test][:, :, ::-1] * 3.0 + 500.0  # other objects, much brighter
    X_train_wild, X_test_wild, ex_wild = features_for_split(name, wild, train, test, **params)
    np.testing.assert_array_equal(X_train, X_train_wild)
    for key, value in ex.learned_state().items():
        np.testing.assert_array_equal(value, ex_wild.learned_state()[key])
    assert ex.learned_state(), "a learned extractor must expose what it learned"
    assert not np.allclose(X_test, X_test_wild)  # the test stacks did change
    # ...and the check has power: fitting on every stack does change what is learned
    everything = extractor(name, **params).fit(wild)
    assert any(not np.array_equal(v, everything.learned_state()[k])
               for k, v in ex_wild.learned_state().items())


def test_intensity_stats_keep_absolute_reflectance_that_hog_removes():
    stacks = _objects(n=2, k=1)
    brighter = stacks.copy()
    object_pixels = stack_masks(stacks)[:, None]
    brighter[object_pixels] *= 1.3  # same object, reflecting 30 % more light
    assert np.abs(stack_features(brighter) - stack_features(stacks)).max() < 0.05
    stats, stats_bright = intensity_stats(stacks), intensity_stats(brighter)
    np.testing.assert_allclose(stats_bright[:, :6], stats[:, :6] * 1.3, rtol=1e-3)


def test_pose_robust_features_ignore_where_the_object_lies():
    stacks = _objects(n=2, k=2)
    moved = np.roll(stacks, (17, -11), axis=(2, 3))  # shifted, object stays inside
    turned = np.ascontiguousarray(np.rot90(stacks, 1, axes=(2, 3)))
    np.testing.assert_allclose(intensity_stats(moved), intensity_stats(stacks), rtol=1e-5)
    np.testing.assert_allclose(intensity_stats(turned), intensity_stats(stacks), rtol=1e-5)
    hog = extractor("hog_grid").fit(stacks)
    pose = extractor("pose_hog").fit(stacks)

    def change(features, other):
        a, b = features(stacks), features(other)
        return np.linalg.norm(a - b) / np.linalg.norm(a)

    # the paper's grid moves with the object; pose normalisation and pooling barely do
    assert change(hog.transform, moved) > 0.3
    assert change(pose.transform, moved) < 0.35 * change(hog.transform, moved)
    assert change(pooled_hog, moved) < 0.35 * change(hog.transform, moved)


def test_mask_moments_find_centre_and_axis():
    masks = np.zeros((2, 120, 120), bool)
    masks[0, 50:60, 20:90] = True  # along the columns
    masks[1, 20:100, 70:80] = True  # along the rows
    centroid, angle, area = mask_moments(masks)
    np.testing.assert_allclose(centroid[0], [54.5, 54.5])
    np.testing.assert_allclose(centroid[1], [59.5, 74.5])
    assert np.isclose(np.cos(angle[0]) ** 2, 1.0) and np.isclose(np.sin(angle[1]) ** 2, 1.0)
    np.testing.assert_array_equal(area, [700, 800])


@pytest.mark.parametrize("name", [n for n in EXTRACTORS if n != "bow"])
def test_restore_from_learned_arrays_transforms_identically(name):
    stacks = _objects(n=6, k=2)
    fitted = extractor(name).fit(stacks[:4])
    state = {k: np.array(v).tolist() for k, v in fitted.learned_state().items()}  # as JSON
    restored = extractor(name).restore(state)
    np.testing.assert_array_equal(restored.transform(stacks), fitted.transform(stacks))
    if state:
        with pytest.raises(ValueError, match="mean and scale"):
            extractor(name).restore({"mean": state["mean"][:-1], "scale": state["scale"]})
