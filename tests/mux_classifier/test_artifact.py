"""Trained-classifier artifact: round trip, file safety and clear errors."""
import json
import os
import re
import stat
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lightstage_physics.rig import DEFAULT_DIMMER, site_to_led_patterns
from mux_classifier.artifact import (FORMAT_VERSION, UNRECORDED_DIMMER, ArtifactError,
                                     DimmerMismatch, TrainedArtifact, check_dimmer,
                                     noise_to_dict)
from mux_classifier.estimator import MuxClassifier

from helpers.artifact_checks import (FUZZ_SETTINGS, SIGMA3, check_header_fields_refused_naming_them,
                                     check_refused_or_classifies, rewrite_artifact, saved_bytes)
from helpers.artifact_mutations import mutated_artifacts



@pytest.fixture(scope="module")
def artifact(toy_stacks):
    stacks, y = toy_stacks
    clfs = [MuxClassifier().fit(stacks[:, :k], y) for k in (1, 2, 3)]
    rng = np.random.default_rng(1)
    P = rng.integers(0, 2, (32, 3)).astype(np.float32)
    return TrainedArtifact.from_classifiers(
        clfs, P, class_names=["apple_real", "apple_fake", "lime_real", "lime_fake"],
        noise=SIGMA3, provenance={"method": "greedy", "accuracy_by_images": {"1": 0.5}, "seed": 3})


def test_round_trip_predicts_identically(artifact, toy_stacks, tmp_path):
    stacks, _ = toy_stacks
    path = tmp_path / "clf.npz"
    artifact.save(path)
    loaded = TrainedArtifact.load(path)
    assert loaded.class_names == artifact.class_names
    assert loaded.noise == SIGMA3 and loaded.mode == "joint"
    assert loaded.provenance == {"method": "greedy", "accuracy_by_images": {"1": 0.5}, "seed": 3}
    assert loaded.hog_config == artifact.hog_config and loaded.n_images == [1, 2, 3]
    np.testing.assert_array_equal(loaded.led_patterns, artifact.led_patterns)
    for k in (1, 2, 3):
        np.testing.assert_array_equal(loaded.decision_function(stacks[:, :k]),
                                      artifact.decision_function(stacks[:, :k]))
        np.testing.assert_array_equal(loaded.predict(stacks[:, :k]), artifact.predict(stacks[:, :k]))
    one = loaded.predict_stack(stacks[5])
    assert one.label == loaded.predict(stacks[5:6])[0] and one.n_images == 3
    assert one.label == loaded.class_names[one.index] and one.scores.shape == (4,)


def test_artifact_scores_equal_the_trained_classifier(artifact, toy_stacks):
    stacks, y = toy_stacks
    clf = MuxClassifier().fit(stacks[:, :2], y)
    np.testing.assert_allclose(artifact.decision_function(stacks[:, :2]),
                               clf.decision_function(stacks[:, :2]))
    restored = artifact.classifier(2)
    np.testing.assert_array_equal(restored.predict(stacks[:, :2]),
                                  np.asarray(artifact.class_names)[clf.predict(stacks[:, :2])])


def test_per_colour_artifact_keeps_site_patterns(toy_stacks, tmp_path):
    stacks, y = toy_stacks
    W = np.zeros((8, 1), np.float32)
    W[[0, 3], 0] = 1
    P = site_to_led_patterns(W)
    assert P.shape == (32, 4)
    # image c of column 0 lights LED site*4 + c of the lit sites only
    for c in range(4):
        assert set(np.flatnonzero(P[:, c])) == {0 * 4 + c, 3 * 4 + c}
    clf = MuxClassifier(estimator="ridge").fit(np.concatenate([stacks, stacks[:, :1]], axis=1), y)
    art = TrainedArtifact.from_classifiers([clf], site_patterns=W, noise=None)
    art.save(tmp_path / "pc.npz")
    loaded = TrainedArtifact.load(tmp_path / "pc.npz")
    assert loaded.mode == "per_colour" and loaded.noise["name"] == "none"
    np.testing.assert_array_equal(loaded.site_patterns, W)


def test_file_is_plain_npz_with_json_header(artifact, tmp_path):
    path = tmp_path / "clf.npz"
    artifact.save(path)
    with np.load(path, allow_pickle=False) as npz:
        header = json.loads(npz["header"].tobytes().decode())
        # the lowest version that holds it (5 only for learned cross-image statistics)
        assert header["format_version"] == 4 < FORMAT_VERSION
        assert npz["coef_2"].shape == (4, 1800)


def test_other_version_is_refused(artifact, tmp_path):
    artifact.save(tmp_path / "a.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "b.npz",
             change_header=lambda h: h.update(format_version=FORMAT_VERSION + 1))
    with pytest.raises(ArtifactError, match=rf"version {FORMAT_VERSION + 1}.*reads version {FORMAT_VERSION}.*Retrain"):
        TrainedArtifact.load(tmp_path / "b.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "c.npz", change_header=lambda h: h.update(format_version=0))
    with pytest.raises(ArtifactError, match=r"version 0; .*reads version 7 and the older 1, 2, 3, 4, 5, 6\."):
        TrainedArtifact.load(tmp_path / "c.npz")


def test_the_dimmer_is_recorded(artifact, tmp_path):
    assert artifact.dimmer == DEFAULT_DIMMER and artifact.dimmer_recorded
    clfs = [artifact.classifier(k) for k in artifact.n_images]
    dim = TrainedArtifact.from_classifiers(clfs, artifact.led_patterns, noise=SIGMA3, dimmer=0.3)
    dim.save(tmp_path / "d.npz")
    with np.load(tmp_path / "d.npz", allow_pickle=False) as npz:
        assert json.loads(npz["header"].tobytes().decode())["dimmer"] == 0.3
    loaded = TrainedArtifact.load(tmp_path / "d.npz")
    assert loaded.dimmer == 0.3 and loaded.dimmer_recorded
    assert loaded.describe().endswith("noise sigma3, dimmer 0.3")
    rewrite_artifact(tmp_path / "d.npz", tmp_path / "e.npz", change_header=lambda h: h.pop("dimmer"))
    with pytest.raises(ArtifactError, match="'dimmer' must be a positive number, got None"):
        TrainedArtifact.load(tmp_path / "e.npz")
    with pytest.raises(ArtifactError, match="dimmer must be a positive number, got nan"):
        TrainedArtifact(artifact.led_patterns, artifact.class_names, artifact.stages,
                        dimmer=float("nan"))


def _as_format_1(header):
    """What the lightstage before format 2 wrote: no dimmer in the header."""
    header.update(format_version=1)
    header.pop("dimmer")
    header.pop("features")


def test_a_format_2_file_loads_with_the_hog_grid_it_always_used(artifact, toy_stacks, tmp_path):
    stacks, _ = toy_stacks
    artifact.save(tmp_path / "a.npz")

    def as_format_2(header):
        header.update(format_version=2)
        header.pop("features")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "two.npz", change_header=as_format_2)
    two = TrainedArtifact.load(tmp_path / "two.npz")
    assert two.features == "hog_grid" and "hog_grid features" in two.describe()
    np.testing.assert_array_equal(two.predict(stacks), artifact.predict(stacks))


def test_an_unknown_or_learning_feature_extractor_is_refused(artifact, tmp_path):
    artifact.save(tmp_path / "a.npz")
    for name, why in (("sift", "unknown feature extractor 'sift'"),
                      ("bow", "learns from images"), (3, "must be the name of a feature")):
        rewrite_artifact(tmp_path / "a.npz", tmp_path / "b.npz",
                 change_header=lambda h, name=name: h.update(features=name))
        with pytest.raises(ArtifactError, match=why):
            TrainedArtifact.load(tmp_path / "b.npz")


def test_a_format_1_file_loads_with_the_dimmer_every_earlier_training_used(artifact, toy_stacks,
                                                                           tmp_path):
    stacks, _ = toy_stacks
    artifact.save(tmp_path / "a.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "old.npz", change_header=_as_format_1)
    old = TrainedArtifact.load(tmp_path / "old.npz")
    assert UNRECORDED_DIMMER == 0.45
    assert old.dimmer == 0.45 and not old.dimmer_recorded
    assert "dimmer 0.45 (not recorded: a format-1 file; every training before format 2 used " \
           "0.45)" in old.describe()
    np.testing.assert_array_equal(old.predict(stacks), artifact.predict(stacks))
    # saved again, it is a file of today's format that records the dimmer
    old.save(tmp_path / "again.npz")
    again = TrainedArtifact.load(tmp_path / "again.npz")
    assert again.dimmer == 0.45 and again.dimmer_recorded


def test_the_bundled_format_1_artifact_still_loads():
    # the classifier bags/sim_session once carried, kept as written then (format 1, no dimmer)
    bundled = Path(__file__).parent / "data" / "format1_classifier.npz"
    with np.load(bundled, allow_pickle=False) as npz:
        assert json.loads(npz["header"].tobytes().decode())["format_version"] == 1
    art = TrainedArtifact.load(bundled)
    assert art.dimmer == 0.45 and not art.dimmer_recorded and "not recorded" in art.describe()


def test_check_dimmer_names_both_values_and_what_to_set():
    check_dimmer(0.45, 0.45)
    check_dimmer(0.45, np.float32(0.45))  # a float32 parameter of the same value
    with pytest.raises(DimmerMismatch, match=r"trained with dimmer 0.45 but the camera's dimmer "
                                             r"is 0.9: .*2 x as bright.*Set the camera node's "
                                             r"dimmer parameter to 0.45"):
        check_dimmer(0.45, 0.9)
    assert issubclass(DimmerMismatch, ArtifactError)  # a node refuses it as any unusable file
    for bad in (0.0, -1.0, float("nan"), None, "x"):
        with pytest.raises(ArtifactError, match="camera's dimmer must be a positive number"):
            check_dimmer(0.45, bad)


def test_truncated_file_is_refused(artifact, tmp_path):
    artifact.save(tmp_path / "a.npz")
    data = (tmp_path / "a.npz").read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ArtifactError, match="truncated"):
        TrainedArtifact.load(tmp_path / "t.npz")


def test_non_npz_and_pickles_are_refused(tmp_path):
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(ArtifactError, match="not an .npz"):
        TrainedArtifact.load(tmp_path / "text.npz")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with zipfile.ZipFile(tmp_path / "pickled.npz", "w") as zf:
        zf.write(tmp_path / "obj.npy", "header.npy")
    with pytest.raises(ArtifactError, match="pickle"):
        TrainedArtifact.load(tmp_path / "pickled.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ArtifactError, match="no header"):
        TrainedArtifact.load(tmp_path / "other.npz")
    with pytest.raises(ArtifactError, match="cannot read"):
        TrainedArtifact.load(tmp_path / "missing.npz")


def test_missing_and_inconsistent_arrays_are_refused(artifact, tmp_path):
    artifact.save(tmp_path / "a.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "b.npz", drop=("coef_2",))
    with pytest.raises(ArtifactError, match="coef_2"):
        TrainedArtifact.load(tmp_path / "b.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "c.npz",
             change_header=lambda h: h.update(class_names=["a", "b", "c"]))
    with pytest.raises(ArtifactError, match=r"expected \(3, 900\)"):
        TrainedArtifact.load(tmp_path / "c.npz")


def test_wrong_stacks_fail_clearly(artifact, toy_stacks):
    stacks, _ = toy_stacks
    with pytest.raises(ArtifactError, match=r"classifiers for \[1, 2, 3\] images, not 4"):
        artifact.predict(np.concatenate([stacks, stacks[:, :1]], axis=1))
    with pytest.raises(ArtifactError, match="120 x 120"):
        artifact.predict_stack(np.zeros((3, 240, 240), np.float32))
    with pytest.raises(ArtifactError, match=r"\(k, H, W\)"):
        artifact.predict_stack(np.zeros((120, 120), np.float32))
    with pytest.raises(ArtifactError, match="expected 2 images per stack, got 3"):
        artifact.decision_function(stacks, n_images=2)


def test_save_does_not_leave_partial_files_on_error(artifact, tmp_path):
    bad = TrainedArtifact(artifact.led_patterns, artifact.class_names, artifact.stages,
                          provenance={"x": float("nan")})
    (tmp_path / "keep.npz").write_bytes(b"old")
    with pytest.raises(ArtifactError, match="JSON"):
        bad.save(tmp_path / "keep.npz")
    assert (tmp_path / "keep.npz").read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.npz"]


def test_construction_is_validated(artifact):
    with pytest.raises(ArtifactError, match=r"led_patterns must be \(32"):
        TrainedArtifact(np.zeros((8, 3)), artifact.class_names, artifact.stages)
    with pytest.raises(ArtifactError, match=r"\[0, 1\]"):
        TrainedArtifact(artifact.led_patterns * 2, artifact.class_names, artifact.stages)
    with pytest.raises(ArtifactError, match="mode"):
        TrainedArtifact(artifact.led_patterns, artifact.class_names, artifact.stages, mode="x")
    with pytest.raises(ArtifactError, match="lacks"):
        noise_to_dict({"name": "sigma3"})


def test_noise_from_object():
    class Model:
        sigma_p2, sigma_r2, gain_db, exposure_ms = 0.25, 8.35, 6.0, 84.0

    assert noise_to_dict(Model(), name="sigma1") == {
        "name": "sigma1", "sigma_p2": 0.25, "sigma_r2": 8.35, "gain_db": 6.0, "exposure_ms": 84.0}


def test_corrupted_bytes_are_refused(artifact, tmp_path):
    artifact.save(tmp_path / "a.npz")
    data = bytearray((tmp_path / "a.npz").read_bytes())
    middle = len(data) // 3
    data[middle:middle + 64] = bytes(64)          # zero a stretch inside a compressed member
    (tmp_path / "c.npz").write_bytes(bytes(data))
    with pytest.raises(ArtifactError, match="not a readable lightstage classifier file"):
        TrainedArtifact.load(tmp_path / "c.npz")


def test_header_that_is_not_an_npy_array_is_refused(tmp_path, monkeypatch):
    """A zip whose header.npy is not an .npy array gave
    AttributeError ('bytes' object has no attribute 'astype')."""
    monkeypatch.chdir(tmp_path)
    zipfile.ZipFile('x.npz', 'w').writestr('header.npy', b'garbage')
    with pytest.raises(ArtifactError, match=r"'x.npz' is not a readable lightstage classifier "
                                            r"file: its members \['header'\] are not .npy arrays"):
        TrainedArtifact.load('x.npz')


def test_paths_that_are_not_regular_files_are_refused(tmp_path):
    for path in ['/dev/zero', str(tmp_path), 'a\0b', 'x' * 5000]:  # endless, a folder, NUL, long
        with pytest.raises(ArtifactError, match="not a regular file|cannot read classifier file"):
            TrainedArtifact.load(path)


@pytest.mark.parametrize("header", [
    b'{"format": "lightstage.mux_classifier", "format_version": NaN}',
    b'{"format": "lightstage.mux_classifier", "format_version": 1e400}',
    b'{"format": "lightstage.mux_classifier", "format_version": -Infinity}',
])
def test_nan_and_huge_header_numbers_are_refused_naming_the_field(header, tmp_path):
    np.savez(tmp_path / "h.npz", header=np.frombuffer(header, np.uint8))
    with pytest.raises(ArtifactError, match="header field 'format_version' is not a finite number"):
        TrainedArtifact.load(tmp_path / "h.npz")


@pytest.mark.parametrize("header", [
    b'[' * 100_000,
    b'\xff\xfe',
])
def test_headers_with_deep_nesting_or_bad_utf8_are_refused(header, tmp_path):
    np.savez(tmp_path / "h.npz", header=np.frombuffer(header, np.uint8))
    with pytest.raises(ArtifactError, match="header is not valid JSON"):
        TrainedArtifact.load(tmp_path / "h.npz")


def test_header_array_of_another_type_is_refused(tmp_path):
    np.savez(tmp_path / "h.npz", header=np.array(["{}"]))
    with pytest.raises(ArtifactError, match=r"header is a <U2 array of shape \(1,\)"):
        TrainedArtifact.load(tmp_path / "h.npz")


@pytest.mark.parametrize("field, value, message", [
    ("n_images", [2.0], "'n_images' must list integers"),
    ("class_names", "abcd", "'class_names' must be a list"),
    ("class_names", [1, 2, 3, 4], "'class_names' must list strings"),
    ("hog_config", None, "'hog_config' must be an object"),
    ("has_site_patterns", "yes", "'has_site_patterns' must be true or false"),
    ("provenance", [1], "'provenance' must be an object"),
    ("noise", {"name": "x", "sigma_p2": 1, "sigma_r2": 1, "gain_db": 0, "exposure_ms": -1},
     "header field 'noise.exposure_ms' = -1 ms is out of range: give 0.001 .. 10000 ms"),
    ("noise", {"name": "x", "sigma_p2": "a", "sigma_r2": 1, "gain_db": 0, "exposure_ms": 1},
     "header field 'noise.sigma_p2' must be a number or null"),
    # a gain no camera has killed the camera node on the next classify
    ("noise", {"name": "x", "sigma_p2": 1, "sigma_r2": 1, "gain_db": 1e6, "exposure_ms": 30},
     "header field 'noise.gain_db' = 1000000.0 dB is out of range: give 0 .. 48 dB"),
    ("noise", {"name": "x", "sigma_p2": 1, "sigma_r2": 1e300, "gain_db": 15, "exposure_ms": 30},
     "header field 'noise.sigma_r2' = 1e+300 is out of range"),
    ("noise", {"name": "x", "sigma_p2": 1, "sigma_r2": 1, "gain_db": 15, "exposure_ms": 30, "y": 1},
     "header field 'noise' has unknown keys ['y']"),
    ("dimmer", None, "'dimmer' must be a positive number"),
    ("dimmer", True, "dimmer must be a positive number, got True"),
    ("dimmer", -0.45, "header field 'dimmer' = -0.45 is out of range: give 0.001 .. 10"),
    ("dimmer", 0, "header field 'dimmer' = 0 is out of range"),
    ("dimmer", 1e6, "header field 'dimmer' = 1000000.0 is out of range"),
    ("hog_config", {"image_size": 1e9}, "header field 'hog_config.image_size' must be a whole number"),
    ("hog_config", {"image_size": 10**9}, "header field 'hog_config.image_size' = 1000000000 is out of range"),
    ("hog_config", {"orientations": -3}, "header field 'hog_config.orientations' = -3 is out of range"),
    ("class_names", ["a"], "header field 'class_names' must list 2 .. 10000 classes, got 1"),
    ("class_names", ["a", ""], "header field 'class_names[1]' must be 1 .. 200 characters"),
    ("n_images", [], "header field 'n_images' lists no image count"),
    ("n_images", [10**12], "header field 'n_images[0]' = 1000000000000 is out of range"),
    ("mode", "sideways", "header field 'mode' must be one of"),
])
def test_malformed_header_fields_are_named(artifact, tmp_path, field, value, message):
    artifact.save(tmp_path / "a.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "b.npz", change_header=lambda h: h.update({field: value}))
    with pytest.raises(ArtifactError, match=re.escape(message)):
        TrainedArtifact.load(tmp_path / "b.npz")


def test_arrays_of_text_are_refused(artifact, tmp_path):
    artifact.save(tmp_path / "a.npz")
    with np.load(tmp_path / "a.npz") as npz:
        arrays = dict(npz)
    arrays["led_patterns"] = arrays["led_patterns"].astype(str)
    np.savez(tmp_path / "b.npz", **arrays)
    with pytest.raises(ArtifactError, match="array 'led_patterns' holds <U32 values, not real numbers"):
        TrainedArtifact.load(tmp_path / "b.npz")


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_saved_file_has_the_mode_the_umask_gives(artifact, tmp_path, umask):
    """Artifacts were written 0600 (mkstemp's mode survived the rename), unreadable
    to a classifier running as another user."""
    old = os.umask(umask)
    try:
        artifact.save(tmp_path / "a.npz")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "a.npz").st_mode) == 0o666 & ~umask
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


@pytest.fixture(scope="module")
def artifact_bytes(artifact, tmp_path_factory):
    return saved_bytes(artifact, tmp_path_factory)


@FUZZ_SETTINGS
@given(data=st.data())
def test_fuzz_malformed_files_raise_only_artifact_error(artifact_bytes, tmp_path_factory, data):
    """Mutated artifact bytes and zip members: the loader answers ArtifactError or loads a
    classifier that classifies; nothing else."""
    path = tmp_path_factory.getbasetemp() / "fuzzed.npz"
    path.write_bytes(data.draw(mutated_artifacts(artifact_bytes)))
    check_refused_or_classifies(path)


def test_fuzz_every_header_field_out_of_range_is_refused_naming_it(artifact, tmp_path):
    """Every header field, set to NaN, inf, negative, huge, another type or a list
    of another length: the file loads (the value is one the format allows) and classifies,
    or is refused with an ArtifactError naming the field."""
    check_header_fields_refused_naming_them(artifact, tmp_path)


