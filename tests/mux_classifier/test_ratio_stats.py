"""The cross-image relief statistics (`ratio_stats`): a relief's shading that turns with the
light shows in them, a print of it does not; layout, and bad input refused."""
import numpy as np
import pytest

from mux_classifier.ratio_stats import (image_pairs, n_ratio_stats, object_masks, pair_ratio_stats,
                                       ratio_stats)

SIZE = 48


def _stage_stacks(relief: bool, n=4, seed=0):
    """n stacks of 3 images: a disk on a dark floor with a printed design (albedo); a
    relief's shading is lit from the left in image 0 and from the right in image 1 (a print
    carries the all-lights shading in its ink, the same in both); image 2 lights it evenly."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:SIZE, :SIZE].astype(np.float64)
    stacks = []
    for _ in range(n):
        cy, cx = rng.uniform(18, SIZE - 18, 2)
        disk = (yy - cy) ** 2 + (xx - cx) ** 2 < 15 ** 2
        design = 0.6 + 0.4 * rng.uniform(0, 1, (SIZE, SIZE))          # ink
        bumps = np.sin(xx / 2.5 + rng.uniform(0, 6)) * np.cos(yy / 3.0)  # the relief's slope
        if relief:
            left, right = 1 + 0.3 * bumps, 1 - 0.3 * bumps
        else:
            left = right = np.ones_like(bumps)
        images = [800 * design * left, 800 * design * right, 800 * design]
        stacks.append([np.where(disk, im, 20.0) for im in images])
    stacks = np.asarray(stacks, np.float32)
    return stacks + rng.normal(0, 2, stacks.shape).astype(np.float32)


def test_a_relief_shows_where_its_print_does_not():
    relief = ratio_stats(_stage_stacks(True), offset=10.0)
    flat = ratio_stats(_stage_stacks(False), offset=10.0)
    assert relief.shape == flat.shape == (4, n_ratio_stats(3))
    # pair (0, 1): the two side lights; its spread and gradient are the relief's
    assert (relief[:, 0] > 5 * flat[:, 0]).all(), (relief[:, 0], flat[:, 0])
    assert (relief[:, 1] > 3 * flat[:, 1]).all(), (relief[:, 1], flat[:, 1])


def test_what_multiplies_every_image_cancels():
    stacks = _stage_stacks(True)
    tinted = stacks.copy()
    tinted[stacks > 100] *= 0.7   # another instance's overall albedo, on the object only
    np.testing.assert_allclose(ratio_stats(tinted, offset=1.0), ratio_stats(stacks, offset=1.0),
                               rtol=0.05, atol=2e-3)


def _whole_image_stats(stacks, offset):
    """The formula over every pixel, in float64: what the crop must reproduce."""
    arr = np.asarray(stacks, np.float64)
    log_images = np.log(np.maximum(arr, 0) + offset).transpose(1, 0, 2, 3)
    return pair_ratio_stats(np, log_images, object_masks(arr).astype(np.float64))


@pytest.mark.parametrize("centre", [(24, 24), (4, 30), (30, 45), (47, 0)])
def test_the_object_crop_in_float32_gives_the_whole_image_values(centre):
    # a small object inside the image, and cut by each border (no gradient on the border)
    stacks = _stage_stacks(True, seed=3)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    outside = (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 >= 9 ** 2
    stacks[:, :, outside] = 20.0
    fast = ratio_stats(stacks, offset=10.0)
    assert fast.dtype == np.float32
    np.testing.assert_allclose(fast, _whole_image_stats(stacks, 10.0), rtol=1e-4, atol=1e-6)


def test_layout_and_bad_input():
    assert image_pairs(4) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert n_ratio_stats(4) == 12 and n_ratio_stats(1) == 0
    dark = np.zeros((2, 2, 8, 8), np.float32)   # no object: the whole image, finite values
    assert np.isfinite(ratio_stats(dark, 1.0)).all()
    assert ratio_stats(dark[:, :1], 1.0).shape == (2, 0)   # one image: no pair
    with pytest.raises(ValueError, match='offset'):
        ratio_stats(dark, 0.0)
    with pytest.raises(ValueError, match=r'\(n, k, H, W\)'):
        ratio_stats(dark[0], 1.0)
