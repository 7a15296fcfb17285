"""`rig.yaml` entries of the wrong kind name their key and value.

`bit_depth: 11.9` used to load as 11 (every gray level doubled) and `image_height: 120.9` as
120; a wrong type gave `invalid literal for int() with base 10: 'one-twenty'` or `malformed
rig description (float() argument must be ... not 'list')`, naming no key.
"""
import re

import numpy as np
import pytest
import yaml

from lightstage_physics.capture_format import (CaptureFormatError, check_equal_poses,
                                               load_capture, write_capture)
from lightstage_physics.rig import Rig

from helpers.camera import make_modelset


@pytest.fixture
def root(tmp_path):
    return write_capture(tmp_path / "cap", make_modelset(n_per_class=2, size=8),
                         compress_level=1)


def _with(root, section, key, value, index=None):
    data = yaml.safe_load((root / "rig.yaml").read_text())
    target = data[section] if index is None else data[section][index]
    target[key] = value
    (root / "rig.yaml").write_text(yaml.safe_dump(data))


def _refused(root, message):
    with pytest.raises(CaptureFormatError, match=re.escape(f"{root / 'rig.yaml'}: {message}")):
        load_capture(root, cache=False)


@pytest.mark.parametrize("key,value", [("bit_depth", 11.9), ("image_height", 120.9),
                                       ("image_width", 8.5), ("frames_averaged", 16.25)])
def test_a_fractional_integer_is_refused_naming_key_and_value(root, key, value):
    _with(root, "camera", key, value)
    _refused(root, f"camera.{key} must be a whole number, got {value}")


def test_a_word_where_an_integer_belongs_names_key_and_value(root):
    _with(root, "camera", "image_height", "one-twenty")
    _refused(root, "camera.image_height must be a whole number, got 'one-twenty'")


@pytest.mark.parametrize("section,key,index", [("camera", "exposure_us", None),
                                               ("camera", "gain_db", None),
                                               ("sites", "x_mm", 3),
                                               ("channels", "wavelength_nm", 2)])
def test_a_list_where_a_float_belongs_names_key_and_value(root, section, key, index):
    _with(root, section, key, [1.0, 2.0], index)
    where = f"{section}." if index is None else f"{section}[{index}]."
    _refused(root, f"{where}{key} must be a finite number, got [1.0, 2.0]")


@pytest.mark.parametrize("value", [True, None, ".nan", ".inf", {"a": 1}])
def test_other_wrong_kinds_are_refused(root, value):
    text = (root / "rig.yaml").read_text()
    (root / "rig.yaml").write_text(re.sub(r"gain_db: .*", f"gain_db: {value}", text))
    with pytest.raises(CaptureFormatError, match=r"camera.gain_db must be a finite number"):
        load_capture(root, cache=False)


def test_whole_floats_and_yaml_exponents_still_load(root):
    """`10.0` is a whole number; `3e4` (no decimal point) is a string to YAML 1.1 but a number
    to a person: both load as meant, as before."""
    text = (root / "rig.yaml").read_text()
    text = re.sub(r"bit_depth: .*", "bit_depth: 12.0", text)
    text = re.sub(r"exposure_us: .*", "exposure_us: 3e4", text)
    (root / "rig.yaml").write_text(text)
    rig = load_capture(root, cache=False).rig
    assert rig.bit_depth == 12 and isinstance(rig.bit_depth, int)
    assert rig.exposure_us == 30000.0
    assert Rig.from_dict(rig.to_dict()) == rig


def test_range_errors_name_the_file(root):
    _with(root, "camera", "bit_depth", 17)
    _refused(root, "bit_depth must be 8..16, got 17")
    _with(root, "camera", "bit_depth", 10)
    _with(root, "camera", "image_height", 0)
    _refused(root, "image_size must be positive")


def test_structure_errors_name_the_key(root):
    data = yaml.safe_load((root / "rig.yaml").read_text())
    (root / "rig.yaml").write_text(yaml.safe_dump({**data, "sites": {"a": 1}}))
    _refused(root, "'sites' must be a list, got {'a': 1}")
    (root / "rig.yaml").write_text(yaml.safe_dump({**data, "camera": [1, 2]}))
    _refused(root, "'camera' must be a mapping of camera settings, got [1, 2]")
    (root / "rig.yaml").write_text(yaml.safe_dump({**data, "sites": [1, 2]}))
    _refused(root, "missing key 'sites[0].name'")


def test_unequal_pose_counts_are_named(tmp_path):
    ms = make_modelset(n_per_class=3, size=8)
    check_equal_poses(ms)  # equal: accepted
    keep = np.ones(len(ms), bool)
    keep[-1] = False
    uneven = ms.subset(np.flatnonzero(keep))
    with pytest.raises(CaptureFormatError, match=r"cap: classes have different numbers of poses "
                                                 r"\(2 pose\(s\): fruit1-fake; 3 pose\(s\): "
                                                 r"fruit0-real\)"):
        check_equal_poses(uneven, "cap")


@pytest.mark.parametrize("key,value,message", [
    ("exposure_us", -30000, "camera.exposure_us = -30000.0 us is out of range: give 1 .. 10000000 us"),
    ("exposure_us", 0, "camera.exposure_us = 0.0 us is out of range"),
    ("frames_averaged", 0, "camera.frames_averaged = 0 is out of range: give 1 .. 100000 frames"),
    ("frames_averaged", -5, "camera.frames_averaged = -5 is out of range"),
    ("gain_db", 1e300, "camera.gain_db = 1e+300 dB is out of range: give 0 .. 48 dB"),
    ("field_of_view_mm", -10, "camera.field_of_view_mm = -10.0 mm is out of range"),
    ("height_mm", 0, "camera.height_mm = 0.0 mm is out of range"),
])
def test_camera_values_out_of_range_are_refused_naming_the_key(root, key, value, message):
    _with(root, "camera", key, value)
    _refused(root, message)


def test_unknown_keys_are_refused_with_the_closest_known_one(root):
    """A typo `frames_averged: 64` silently became the default 1."""
    data = yaml.safe_load((root / "rig.yaml").read_text())
    data["camera"]["frames_averged"] = 64
    (root / "rig.yaml").write_text(yaml.safe_dump(data))
    _refused(root, "unknown key 'camera.frames_averged' (did you mean 'camera.frames_averaged'?)"
             .replace("'camera.frames_averaged' (", "'camera.frames_averged' ("))
    del data["camera"]["frames_averged"]
    data["cammera"] = {}
    (root / "rig.yaml").write_text(yaml.safe_dump(data))
    _refused(root, "unknown key 'cammera' (did you mean 'camera'?)")
