import numpy as np
import pytest

from lightstage_physics.rig import CHANNELS, Rig, led_index
from lightstage_physics.scene_models import ModelSet, downscale_images

from helpers.camera import make_modelset


def test_rig_yaml_roundtrip(tmp_path):
    rig = Rig.paper_default(240)
    rig.save_yaml(tmp_path / "rig.yaml")
    back = Rig.load_yaml(tmp_path / "rig.yaml")
    assert back == rig
    assert rig.n_sites == 8 and rig.max_level == 1023 and back.image_size == (240, 240)
    pos = rig.site_positions_mm()
    assert np.allclose(np.hypot(pos[:, 0], pos[:, 1]).max(), 223 * 0.95)


def test_led_index_site_major():
    assert led_index(0, "red") == 0 and led_index(7, "nir") == 31 and led_index(2, 1) == 9
    assert CHANNELS == ("red", "green", "blue", "nir")
    with pytest.raises(ValueError, match="unknown channel"):
        led_index(0, "uv")


def test_subset_and_object_type():
    ms = make_modelset(n_per_class=3, size=12, n_classes=4)
    sub = ms.subset(ms.labels == 2)
    assert len(sub) == 3 and set(sub.labels) == {2} and sub.class_names == ms.class_names
    np.testing.assert_array_equal(sub.models, ms.models[6:9])
    assert sub.object_type == ["fruit2"] * 3 and ms.object_types[:2] == ["fruit0", "fruit1"]


def test_downscaled_block_mean_and_noise_scale():
    ms = make_modelset(size=24)
    small = ms.downscaled(12)
    assert small.models.shape[-2:] == (12, 12) and small.noise_scale == 0.25
    assert small.rig.image_size == (12, 12)
    expected = ms.models.reshape(*ms.models.shape[:3], 12, 2, 12, 2).mean(axis=(4, 6))
    np.testing.assert_allclose(small.models, expected, rtol=1e-6)
    assert small.downscaled(4).noise_scale == pytest.approx(1 / 36)


def test_downscale_non_integer_factor_variance():
    rng = np.random.default_rng(0)
    noise = rng.standard_normal((20, 90, 90)).astype(np.float32)
    out, factor = downscale_images(noise, 40)
    assert out.shape == (20, 40, 40)
    assert out.var() == pytest.approx(factor, rel=0.05)
    with pytest.raises(ValueError, match="larger"):
        downscale_images(noise, 100)


def test_modelset_validation():
    ms = make_modelset(size=8)
    with pytest.raises(ValueError, match="labels"):
        ModelSet(ms.models, ms.labels[:-1], ms.class_names, ms.sample_names, ms.pose_index,
                 ms.instance, ms.rig)
    with pytest.raises(ValueError, match="sites"):
        ModelSet(ms.models[:, :, :5], ms.labels, ms.class_names, ms.sample_names,
                 ms.pose_index, ms.instance, ms.rig)
