"""hog_batch must equal skimage.feature.hog (paper configuration and others)."""
import numpy as np
import pytest
from skimage.feature import hog as skimage_hog

from mux_classifier.hog import HogConfig, hog_batch, hog_batch_numpy


def reference(images, config=HogConfig()):
    return np.stack([
        skimage_hog(np.asarray(img, dtype=np.float32), orientations=config.orientations,
                    pixels_per_cell=(config.cell_px,) * 2,
                    cells_per_block=(config.block_cells,) * 2,
                    block_norm=config.block_norm, feature_vector=True)
        for img in images
    ])


def structured_images(size=120):
    yy, xx = np.mgrid[:size, :size].astype(np.float64)
    return np.stack([
        (np.sin(xx / 7.0) + np.cos(yy / 5.0)) * 400 + 512,   # smooth texture
        (xx > size // 2) * 1000.0,                            # vertical edge
        (yy > size // 3) * 1000.0,                            # horizontal edge
        ((xx - 60) ** 2 + (yy - 60) ** 2 < 900) * 800.0,     # disc: every orientation
        xx * 3 + yy * 5,                                      # plane
        (xx + yy) % 2 * 1023.0,                               # checkerboard
        xx - yy,                                              # exact 45 / 135 degrees
        np.where(xx > 60, 0.0, 1023.0),                       # edge of negative gradient (180 deg)
    ]).astype(np.float32)


def test_paper_config_has_900_features():
    config = HogConfig()
    assert (config.image_size, config.cell_px, config.block_cells, config.orientations) == (120, 12, 10, 9)
    assert config.n_features == 900


@pytest.mark.parametrize("kind", ["uniform", "integer", "tiny", "binary", "negative"])
def test_random_images_match_skimage(kind):
    rng = np.random.default_rng(["uniform", "integer", "tiny", "binary", "negative"].index(kind))
    shape = (12, 120, 120)
    images = {
        "uniform": rng.uniform(0, 1023, shape),
        "integer": rng.integers(0, 1024, shape),
        "tiny": rng.uniform(0, 1e-3, shape),
        "binary": rng.integers(0, 2, shape) * 1023.0,
        "negative": rng.normal(0, 300, shape),
    }[kind].astype(np.float32)
    got = hog_batch(images)
    assert got.dtype == np.float32 and got.shape == (12, 900)
    np.testing.assert_allclose(got, reference(images), rtol=0, atol=1e-6)


def test_structured_images_match_skimage():
    images = structured_images()
    np.testing.assert_allclose(hog_batch(images), reference(images), rtol=0, atol=1e-6)


def test_constant_image_gives_zero_descriptor():
    images = np.full((2, 120, 120), 517.0, dtype=np.float32)
    got = hog_batch(images)
    assert not got.any()
    np.testing.assert_array_equal(got, reference(images))


def test_batching_does_not_change_values():
    rng = np.random.default_rng(3)
    images = rng.uniform(0, 1023, (37, 120, 120)).astype(np.float32)
    whole = hog_batch(images, HogConfig(batch_size=64))
    for batch_size in (1, 5, 16):
        np.testing.assert_array_equal(hog_batch(images, HogConfig(batch_size=batch_size)), whole)
    np.testing.assert_array_equal(hog_batch(images[7:8]), whole[7:8])


def test_integer_and_float64_inputs_are_computed_like_float32():
    rng = np.random.default_rng(4)
    images = rng.integers(0, 1024, (3, 120, 120)).astype(np.uint16)
    np.testing.assert_array_equal(hog_batch(images), hog_batch(images.astype(np.float32)))
    np.testing.assert_array_equal(hog_batch(images.astype(np.float64)),
                                  hog_batch(images.astype(np.float32)))


@pytest.mark.parametrize("config", [
    HogConfig(image_size=64, cell_px=8, block_cells=3),
    HogConfig(image_size=70, cell_px=8, block_cells=2, orientations=7, block_norm="L1"),
    HogConfig(image_size=40, cell_px=6, block_cells=2, block_norm="L2"),
    HogConfig(image_size=40, cell_px=6, block_cells=2, block_norm="L1-sqrt"),
])
def test_other_configurations_match_skimage(config):
    rng = np.random.default_rng(5)
    images = rng.uniform(0, 1023, (4, config.image_size, config.image_size)).astype(np.float32)
    got = hog_batch(images, config)
    assert got.shape == (4, config.n_features)
    np.testing.assert_allclose(got, reference(images, config), rtol=0, atol=1e-6)


def test_empty_batch():
    assert hog_batch(np.zeros((0, 120, 120), np.float32)).shape == (0, 900)


@pytest.mark.parametrize("shape, message", [
    ((120, 120), "one image"),
    ((2, 100, 120), "120 x 120"),
    ((2, 2, 120, 120), r"\(N, H, W\)"),
])
def test_wrong_shapes_are_rejected_clearly(shape, message):
    with pytest.raises(ValueError, match=message):
        hog_batch(np.zeros(shape, np.float32))


def test_non_finite_gray_levels_are_rejected():
    images = np.zeros((3, 120, 120), np.float32)
    images[1, 5, 5] = np.nan
    with pytest.raises(ValueError, match=r"images \[1\].*NaN"):
        hog_batch(images)


def test_bad_config_is_rejected():
    with pytest.raises(ValueError, match="block_norm"):
        HogConfig(block_norm="L3")
    with pytest.raises(ValueError, match="fewer than one block"):
        HogConfig(image_size=60)
    with pytest.raises(ValueError, match="cell_px"):
        HogConfig(cell_px=0)


def test_config_dict_round_trip():
    config = HogConfig(image_size=64, cell_px=8, block_cells=3)
    assert HogConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match="unknown"):
        HogConfig.from_dict({**config.to_dict(), "cells": 3})


@pytest.mark.parametrize("scale", [1e-42, 1e-20, 1e20, 1e36])
def test_extreme_gray_level_scales_match_skimage(scale):
    # subnormal and huge float32 values: no overflow, no out-of-range bins
    rng = np.random.default_rng(6)
    images = (rng.uniform(0, 1, (3, 120, 120)) * scale).astype(np.float32)
    got = hog_batch(images)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, reference(images), rtol=0, atol=1e-6)


def test_mixed_tiny_and_zero_gradients_match_skimage():
    rng = np.random.default_rng(7)
    images = rng.uniform(0, 1, (3, 120, 120)).astype(np.float32)
    images[:, ::2] = 1e-44
    images[:, :, ::3] = 0
    np.testing.assert_allclose(hog_batch(images), reference(images), rtol=0, atol=1e-6)


# --- the compiled kernel (hog_batch) against the pure-numpy reference (hog_batch_numpy) ---

def _kernel_cases():
    rng = np.random.default_rng(11)
    shape = (6, 120, 120)
    saturated = np.clip(rng.normal(900, 300, shape), 0, 1023)   # large areas clipped at 1023
    saturated[:, 40:80, 40:80] = 1023.0
    return {
        "random": rng.uniform(0, 1023, shape),
        "noisy integers": rng.poisson(30, shape).astype(np.float64),
        "constant": np.full(shape, 517.0),
        "saturated": saturated,
        "tiny gray levels": rng.uniform(0, 1e-3, shape),
        "subnormal": rng.uniform(0, 1, shape) * 1e-42,
        "huge (float32 squares overflow)": rng.uniform(0, 1, shape) * 1e36,
        "structured": structured_images(),
    }


@pytest.mark.parametrize("kind", list(_kernel_cases()))
def test_compiled_kernel_equals_numpy_reference(kind):
    images = _kernel_cases()[kind].astype(np.float32)
    got = hog_batch(images)
    ref = hog_batch_numpy(images)
    assert got.dtype == np.float32 and got.shape == ref.shape
    # same bins and cell histograms; the block norms' float64 sums may round differently
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-7)
    np.testing.assert_allclose(got, reference(images), rtol=0, atol=1e-6)


def test_compiled_kernel_bins_gradients_on_bin_edges_like_the_reference():
    # gradients at (or one float32 step from) every bin edge, and near 0 / 180 degrees:
    # the cases where the cross-product test hands over to the exact atan2 binning
    rng = np.random.default_rng(12)
    angles = np.deg2rad(np.concatenate([np.arange(0, 361, 20.0), np.arange(0, 361, 20.0) + 1e-6,
                                        np.arange(0, 361, 20.0) - 1e-6]))
    size = 120
    images = []
    for k in range(4):
        img = np.zeros((size, size), np.float64)
        # an image of planes, each with one gradient direction, pixel blocks of 6 x 6
        for i in range(0, size, 6):
            for j in range(0, size, 6):
                a = angles[rng.integers(angles.size)]
                yy, xx = np.mgrid[i:i + 6, j:j + 6]
                img[i:i + 6, j:j + 6] = 500 + 40 * (np.sin(a) * yy + np.cos(a) * xx) * (k + 1) / 4
        images.append(img)
    images = np.stack(images).astype(np.float32)
    np.testing.assert_allclose(hog_batch(images), hog_batch_numpy(images), rtol=0, atol=1e-7)


@pytest.mark.parametrize("config", [
    HogConfig(image_size=16, cell_px=4, block_cells=2),                    # tiny images
    HogConfig(image_size=9, cell_px=3, block_cells=3, orientations=4),     # 4 bins: 45/90/135 edges
    HogConfig(image_size=70, cell_px=8, block_cells=2, orientations=7, block_norm="L1"),
    HogConfig(image_size=40, cell_px=6, block_cells=2, block_norm="L1-sqrt"),
    HogConfig(image_size=120, cell_px=8, block_cells=2),                   # the BoW descriptors
    HogConfig(image_size=12, cell_px=12, block_cells=1, orientations=1),   # numpy path
])
def test_compiled_kernel_other_configurations(config):
    rng = np.random.default_rng(13)
    size = config.image_size
    images = np.concatenate([
        rng.uniform(0, 1023, (3, size, size)),
        rng.integers(0, 4, (3, size, size)) * 100.0,    # exact 45 / 90 / 135 degree gradients
    ]).astype(np.float32)
    got = hog_batch(images, config)
    np.testing.assert_allclose(got, hog_batch_numpy(images, config), rtol=0, atol=1e-7)
    np.testing.assert_allclose(got, reference(images, config), rtol=0, atol=1e-6)


def test_compiled_kernel_refuses_non_finite_like_the_reference():
    images = np.zeros((4, 120, 120), np.float32)
    images[2, 0, 0] = np.inf          # a corner pixel: no gradient uses it in both directions
    images[3, 119, 60] = np.nan
    for fn in (hog_batch, hog_batch_numpy):
        with pytest.raises(ValueError, match=r"images \[2, 3\].*NaN"):
            fn(images)
