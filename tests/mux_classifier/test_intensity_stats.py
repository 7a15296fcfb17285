"""The compiled per-image reflectance statistics against their exact numpy reference: level
quantiles within a histogram bin, means exact, each image's features its own."""
import numpy as np
import pytest

from mux_classifier.intensity_stats import (N_BINS, N_STATS, _gradient_magnitude,
                                            intensity_stats, intensity_stats_images,
                                            intensity_stats_images_numpy)
from mux_classifier.object_mask import MASK_FRACTION, image_masks

LEVELS, MEANS, GRADIENT_QUANTILES = slice(0, 5), slice(5, 7), slice(7, 9)


def _objects(n, seed=0, size=120, extent=(15, 50)):
    """Bright textured rectangles of random size, place and brightness on a dark noisy floor
    (10-bit levels, clipped like rendered images)."""
    rng = np.random.default_rng(seed)
    images = rng.normal(40, 4, (n, size, size)).astype(np.float32)
    for i in range(n):
        h, w = rng.integers(*extent, 2)
        r0, c0 = rng.integers(2, size - max(h, w) - 2, 2)
        images[i, r0:r0 + h, c0:c0 + w] += 200 + 300 * rng.random() + rng.normal(0, 30, (h, w))
        images[i, r0 + h // 3:r0 + h // 2, c0 + 2:c0 + w // 2] += 150  # relief
    return np.clip(images, 0, 1023)


def _exact_threshold_is_clear(images, bins=2.0):
    """True when no pixel lies within `bins` level bins of its image's exact mask threshold,
    so the kernel's threshold (within a bin of it) splits the pixels the same way."""
    flat = images.reshape(len(images), -1).astype(np.float64)
    floor, top = np.percentile(flat, [50, 99], axis=1)
    threshold = floor + MASK_FRACTION * np.maximum(top - floor, 1e-6)
    width = (flat.max(axis=1) - flat.min(axis=1)) / N_BINS
    return bool((np.abs(flat - threshold[:, None]) > bins * width[:, None]).all())


def _assert_close_to_reference(images, fast, exact):
    """Level quantiles within 1.5 bins of the image's range, gradient quantiles within 1.5 bins
    of [0, the object's largest gradient], means to float32 rounding."""
    arr = images.astype(np.float32)
    level_bin = (arr.max(axis=(1, 2)) - arr.min(axis=(1, 2))) / N_BINS
    masks = image_masks(arr)
    masks[~masks.any(axis=(1, 2))] = True
    grad = _gradient_magnitude(arr)
    grad_bin = np.array([g[m].max() for g, m in zip(grad, masks)]) / N_BINS
    assert np.all(np.abs(fast[:, LEVELS] - exact[:, LEVELS]) <= 1.5 * level_bin[:, None] + 1e-4)
    np.testing.assert_allclose(fast[:, MEANS], exact[:, MEANS], rtol=1e-5, atol=1e-5)
    assert np.all(np.abs(fast[:, GRADIENT_QUANTILES] - exact[:, GRADIENT_QUANTILES])
                  <= 1.5 * grad_bin[:, None] + 1e-4)


def test_kernel_matches_the_exact_reference_on_objects():
    images = _objects(64)
    assert _exact_threshold_is_clear(images)  # the masks agree: the test data's premise
    fast, exact = intensity_stats_images(images), intensity_stats_images_numpy(images)
    assert fast.dtype == np.float32 and fast.shape == (64, N_STATS)
    assert np.isfinite(fast).all()
    _assert_close_to_reference(images, fast, exact)
    # ...and unbiased: the r-th of a bin's c pixels is put at (r + 1/2) / c of the bin, so for
    # levels spread evenly within bins the mean error is at most a quarter of a bin
    level_bin = (images.max(axis=(1, 2)) - images.min(axis=(1, 2))) / N_BINS
    assert (np.abs(fast[:, LEVELS] - exact[:, LEVELS]) / level_bin[:, None]).mean() < 0.3


def test_object_levels_spread_across_the_threshold():
    """Object levels uniform from well below to far above the mask's threshold: the mask's
    rule decides which pixels count, and only pixels within a bin of it may differ."""
    rng = np.random.default_rng(8)
    images = rng.normal(40, 4, (16, 120, 120)).astype(np.float32)
    for image in images:
        h, w = rng.integers(40, 70, 2)
        r0, c0 = rng.integers(2, 118 - max(h, w), 2)
        image[r0:r0 + h, c0:c0 + w] = rng.uniform(100, 900, (h, w))
    fast, exact = intensity_stats_images(images), intensity_stats_images_numpy(images)
    level_bin = (images.max(axis=(1, 2)) - images.min(axis=(1, 2))) / N_BINS
    # a pixel flipping at the threshold moves a quantile's rank by one: still within ~a bin
    assert np.all(np.abs(fast[:, LEVELS] - exact[:, LEVELS]) <= 1.5 * level_bin[:, None])
    # each flipped pixel (within a bin and a half of the exact threshold) moves the mean by
    # at most the image's range over the object's pixel count
    masks = image_masks(images)
    flat = images.reshape(16, -1)
    floor, top = np.percentile(flat, [50, 99], axis=1)
    threshold = floor + MASK_FRACTION * np.maximum(top - floor, 1e-6)
    near = (np.abs(flat - threshold[:, None]) <= 1.5 * level_bin[:, None]).sum(axis=1)
    bound = (near + 1) * N_BINS * level_bin / (masks.sum(axis=(1, 2)) - near)
    assert np.all(np.abs(fast[:, 5] - exact[:, 5]) <= bound)


def test_tiny_object_and_all_object_images():
    tiny = _objects(8, seed=1, extent=(13, 16))  # ~1.5 % of the image: just above the 99th
    assert _exact_threshold_is_clear(tiny)
    _assert_close_to_reference(tiny, intensity_stats_images(tiny),
                               intensity_stats_images_numpy(tiny))
    rng = np.random.default_rng(2)
    # the object fills the image: two textured regions, the brighter one above the threshold
    full = rng.normal(300, 10, (6, 120, 120)).astype(np.float32)
    full[:, :, 70:] += 400
    assert _exact_threshold_is_clear(full)
    fast, exact = intensity_stats_images(full), intensity_stats_images_numpy(full)
    _assert_close_to_reference(full, fast, exact)
    assert np.all(fast[:, 0] > 600)  # only the bright region is the object


def test_constant_and_flat_images_take_the_whole_image():
    constant = np.full((2, 120, 120), 7.5, np.float32)
    np.testing.assert_array_equal(intensity_stats_images(constant),
                                  [[7.5] * 6 + [0.0] * 3] * 2)
    # 60 % of the pixels at the top level: median = 99th percentile, no pixel above it
    flat = np.full((1, 120, 120), 100, np.uint16)
    flat[:, :48] = 50
    fast = intensity_stats_images(flat)
    np.testing.assert_array_equal(fast[:, :6], intensity_stats_images_numpy(flat)[:, :6])
    np.testing.assert_array_equal(fast[0, :6], [50, 50, 100, 100, 100, 80])


def test_integer_images_get_exact_level_quantiles():
    images = _objects(16, seed=3)
    levels = np.round(images).astype(np.uint16)
    fast, exact = intensity_stats_images(levels), intensity_stats_images_numpy(levels)
    # 10-bit levels: one histogram bin per level, so the mask and level statistics are exact
    np.testing.assert_allclose(fast[:, :7], exact[:, :7], rtol=1e-6)
    _assert_close_to_reference(levels, fast, exact)
    np.testing.assert_allclose(intensity_stats_images(levels.astype(np.float32)), fast,
                               atol=1.5 * 1023 / N_BINS)


def test_each_image_depends_on_itself_alone():
    images = _objects(12, seed=4)
    alone = intensity_stats_images(images)
    order = np.random.default_rng(5).permutation(12)
    np.testing.assert_array_equal(intensity_stats_images(images[order]), alone[order])
    other = images.copy()
    other[1:] = other[1:, ::-1] * 2.5 + 300  # every other image replaced
    np.testing.assert_array_equal(intensity_stats_images(other)[0], alone[0])
    for j in range(12):
        np.testing.assert_array_equal(intensity_stats_images(images[j:j + 1])[0], alone[j])


def test_stacks_are_their_images_in_order_and_prefixes():
    images = _objects(12, seed=6)
    stacks = images.reshape(4, 3, 120, 120)
    out = intensity_stats(stacks)
    assert out.shape == (4, 3 * N_STATS) and out.dtype == np.float32
    np.testing.assert_array_equal(out, intensity_stats_images(images).reshape(4, -1))
    np.testing.assert_array_equal(intensity_stats(stacks[:, :2]), out[:, :2 * N_STATS])


def test_bad_input_is_refused_with_the_reason():
    images = _objects(3, seed=7)
    images[1, 5, 5] = np.nan
    with pytest.raises(ValueError, match=r"images \[1\].*NaN"):
        intensity_stats_images(images)
    huge = np.zeros((2, 5, 5), np.float32)
    huge[1, 1, 2], huge[1, 2, 2], huge[1, 3, 2] = -3e38, 3e38, 3e38  # centre's gradient: inf
    with pytest.raises(ValueError, match=r"images \[1\].*overflow"):
        intensity_stats_images(huge)
    with pytest.raises(ValueError, match="images\\[None\\]"):
        intensity_stats_images(images[0])
    with pytest.raises(ValueError, match="no pixel"):
        intensity_stats_images(np.zeros((2, 0, 5)))
    with pytest.raises(ValueError, match="dtype"):
        intensity_stats_images(np.zeros((2, 4, 4), complex))
    with pytest.raises(ValueError, match=r"\(n, k, H, W\)"):
        intensity_stats(images)
    assert intensity_stats_images(np.zeros((0, 8, 8))).shape == (0, N_STATS)
