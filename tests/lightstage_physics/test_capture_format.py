import os
import shutil

import numpy as np
import pytest
import yaml
from PIL import Image

from lightstage_physics.capture_format import (CaptureFormatError, load_capture, to_raw16,
                                               write_capture)

from helpers.camera import make_modelset


@pytest.fixture
def capture(tmp_path):
    ms = make_modelset(n_per_class=3, size=16, n_classes=2)
    ms.models[0, 0, 0, 0, 0] = 5000.0  # beyond the range: clipped when written
    root = write_capture(tmp_path / "cap", ms, compress_level=1)
    return ms, root


def test_round_trip(capture):
    ms, root = capture
    back = load_capture(root, cache=False)
    expected = to_raw16(ms.models, 10).astype(np.float32) / 64
    np.testing.assert_array_equal(back.models, expected)
    assert np.abs(back.models - np.clip(ms.models, 0, 1023.99)).max() <= 1 / 128 + 1e-6
    assert back.class_names == ms.class_names and back.sample_names == ms.sample_names
    np.testing.assert_array_equal(back.labels, ms.labels)
    np.testing.assert_array_equal(back.pose_index, ms.pose_index)
    np.testing.assert_array_equal(back.instance, ms.instance)
    assert back.rig == ms.rig and back.object_type[0] == "fruit0"
    raw = np.asarray(Image.open(root / "fruit0-real/s0/p00/s0_red.png"))
    assert raw.dtype == np.uint16 and raw[0, 0] == 65535  # MSB-aligned, clipped


def test_cache_gives_identical_arrays_and_tracks_changes(capture):
    _, root = capture
    first = load_capture(root)
    assert (root / ".cache" / "models_u16.npy").is_file()
    second = load_capture(root)
    np.testing.assert_array_equal(first.models, second.models)
    assert second.sample_names == first.sample_names
    np.testing.assert_array_equal(load_capture(root, cache=False).models, second.models)
    # change one image: the cache must not serve stale data
    target = root / "fruit1-fake/s0/p01/s4_nir.png"
    Image.fromarray(np.full((16, 16), 640, np.uint16)).save(target)
    st = target.stat()
    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))
    third = load_capture(root)
    i = third.sample_names.index("fruit1-fake/s0/p01")
    assert np.all(third.models[i, 3, 4] == 10.0)


def test_load_downscaled(capture):
    ms, root = capture
    small = load_capture(root, downscale_to=8)
    full = load_capture(root)
    np.testing.assert_allclose(small.models, full.downscaled(8).models, rtol=1e-6)
    assert small.noise_scale == 0.25 and small.rig.image_size == (8, 8)


def _expect(root, pattern, name_part):
    with pytest.raises(CaptureFormatError, match=pattern) as info:
        load_capture(root, cache=False)
    assert name_part in str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_image(capture):
    _, root = capture
    (root / "fruit0-real/s1/p02/s3_green.png").unlink()
    _expect(root, "missing image", "s1/p02/s3_green.png")


def test_wrong_size(capture):
    _, root = capture
    Image.fromarray(np.zeros((16, 15), np.uint16)).save(root / "fruit0-real/s0/p01/s2_blue.png")
    _expect(root, "16x15", "p01/s2_blue.png")


def test_wrong_bit_depth(capture):
    _, root = capture
    Image.fromarray(np.zeros((16, 16), np.uint8)).save(root / "fruit1-fake/s0/p00/s0_red.png")
    _expect(root, "8-bit gray", "fruit1-fake/s0/p00/s0_red.png")


def test_rgb_image(capture):
    _, root = capture
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(root / "fruit1-fake/s0/p00/s0_red.png")
    _expect(root, "RGB", "s0_red.png")


def test_unknown_channel(capture):
    _, root = capture
    shutil.copy(root / "fruit0-real/s0/p00/s0_red.png", root / "fruit0-real/s0/p00/s0_uv.png")
    _expect(root, "unknown channel 'uv'", "s0_uv.png")


def test_site_out_of_range_and_bad_name(capture):
    _, root = capture
    extra = root / "fruit0-real/s0/p00/s8_red.png"
    shutil.copy(root / "fruit0-real/s0/p00/s0_red.png", extra)
    _expect(root, "site 8", "s8_red.png")
    extra.rename(root / "fruit0-real/s0/p00/red_0.png")
    _expect(root, "is not named", "red_0.png")


def test_corrupt_png(capture):
    _, root = capture
    (root / "fruit0-real/s0/p00/s5_nir.png").write_bytes(b"not a png")
    _expect(root, "cannot be read", "s5_nir.png")


def test_rig_problems(capture):
    _, root = capture
    data = yaml.safe_load((root / "rig.yaml").read_text())
    data["channels"][3]["name"] = "uv"
    (root / "rig.yaml").write_text(yaml.safe_dump(data))
    _expect(root, "unknown channel", "rig.yaml")
    data["channels"][3]["name"] = "nir"
    data["camera"]["bit_depth"] = 12
    (root / "rig.yaml").write_text(yaml.safe_dump(data))
    loaded = load_capture(root, cache=False)  # 12-bit: same raw values, 4x the gray levels
    assert loaded.rig.max_level == 4095
    (root / "rig.yaml").write_text("sites: [unclosed")
    _expect(root, "rig.yaml", "rig.yaml")
    del data["camera"]
    (root / "rig.yaml").write_text(yaml.safe_dump(data))
    _expect(root, "missing key 'camera'", "rig.yaml")
    (root / "rig.yaml").unlink()
    _expect(root, "missing", "rig.yaml")


def test_empty_folders(tmp_path):
    ms = make_modelset(n_per_class=1, size=8)
    root = write_capture(tmp_path / "c", ms, compress_level=1)
    (root / "extra-label").mkdir()
    _expect(root, "no sample folders", "extra-label")
    with pytest.raises(CaptureFormatError, match="not a directory"):
        load_capture(tmp_path / "nope")


def test_write_from_arrays(tmp_path):
    ms = make_modelset(n_per_class=2, size=8)
    root = write_capture(tmp_path / "c", {"models": ms.models, "labels": ms.labels,
                                          "class_names": ms.class_names}, rig=ms.rig)
    back = load_capture(root, cache=False)
    assert len(back) == 4 and back.sample_names[0] == "fruit0-real/s0/p00"
