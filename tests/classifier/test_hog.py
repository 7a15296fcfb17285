"""hog_batch must equal skimage.feature.hog (paper configuration and others)."""
import numpy as np
import pytest
from skimage.feature import hog as skimage_hog

from mux_classifier.hog import HogConfig, hog_batch


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
