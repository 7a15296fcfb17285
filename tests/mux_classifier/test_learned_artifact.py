"""A learned-illumination model in the artifact (format 4): its arrays in the npz
(no pickle), one prediction path (the artifact's estimator per image count), bad files
refused naming the field."""
import json
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mux_classifier.artifact import FORMAT_VERSION, ArtifactError, TrainedArtifact
from mux_classifier.artifact_format import GROUPS_SINCE, LEARNED_PREFIX
from mux_classifier.estimator import LearnedModelClassifier
from mux_classifier.learned_model import LearnedModel

from helpers.artifact_mutations import mutated_artifacts
from helpers.artifact_checks import (FUZZ_SETTINGS, SIGMA3, rewrite_artifact,
                           check_header_fields_refused_naming_them, check_refused_or_classifies,
                           saved_bytes)

NAMES = ["apple_real", "apple_fake", "lime_real", "lime_fake"]


def learned_model(k=3, n_hidden=0, binary=False, seed=0, stacks=None):
    """Random patterns and head; z-scored by the features of `stacks` (n, k, H, W) if given,
    so that the head's logits vary from stack to stack."""
    rng = np.random.default_rng(seed)
    patterns = rng.uniform(0, 1, (32, k))
    if binary:
        patterns = (patterns > 0.5).astype(np.float32)
    sizes = [k * 9] + ([n_hidden] if n_hidden else []) + [len(NAMES)]
    layers = [(rng.normal(0, 1, (a, b)), rng.normal(0, 0.1, b)) for a, b in zip(sizes, sizes[1:])]
    mean, scale = rng.normal(50, 10, k * 9), rng.uniform(5, 20, k * 9)
    model = LearnedModel(patterns, mean, scale, layers, NAMES)
    if stacks is not None:
        F = model.features(stacks)
        model = LearnedModel(patterns, F.mean(axis=0), F.std(axis=0) + 1e-3, layers, NAMES)
    return model


@pytest.fixture(scope="module")
def learned(toy_stacks):
    return TrainedArtifact.from_learned(learned_model(n_hidden=5, stacks=toy_stacks[0]), noise=SIGMA3,
                                        provenance={"method": "learned", "seed": 3})


def test_round_trip_predicts_as_the_numpy_model(learned, toy_stacks, tmp_path):
    stacks, _ = toy_stacks
    learned.save(tmp_path / "l.npz")
    loaded = TrainedArtifact.load(tmp_path / "l.npz")
    assert loaded.mode == "learned" and loaded.features == "intensity_stats"
    assert loaded.n_images == [3] and loaded.class_names == NAMES and loaded.noise == SIGMA3
    assert loaded.provenance == {"method": "learned", "seed": 3}
    np.testing.assert_array_equal(loaded.led_patterns, learned.learned.patterns)
    model = learned.learned
    # the one prediction path: the artifact's estimator for its image count
    assert isinstance(loaded.classifier(3), LearnedModelClassifier)
    np.testing.assert_allclose(loaded.decision_function(stacks),
                               model.logits_from_features(model.features(stacks)), rtol=1e-6)
    np.testing.assert_array_equal(loaded.predict(stacks), np.asarray(NAMES)[model.predict(stacks)])
    one = loaded.predict_stack(stacks[5])
    assert one.label == NAMES[model.predict(stacks[5:6])[0]] and one.n_images == 3
    # the classes are told apart: not every stack gets the same label (else the check is void)
    assert len(set(loaded.predict(stacks))) > 1
    assert "learned graded patterns (2-layer head)" in loaded.describe()
    with pytest.raises(ArtifactError, match=r"classifiers for \[3\] images, not 2"):
        loaded.predict(stacks[:, :2])


def test_every_array_of_the_model_is_stored_under_the_prefix(learned, tmp_path):
    learned.save(tmp_path / "l.npz")
    with np.load(tmp_path / "l.npz", allow_pickle=False) as npz:
        header = json.loads(npz["header"].tobytes().decode())
        stored = {name[len(LEARNED_PREFIX):]: npz[name] for name in npz.files
                  if name.startswith(LEARNED_PREFIX)}
        assert not any(name.startswith("coef_") for name in npz.files)
    assert header["format_version"] == 4 and header["mode"] == "learned"
    assert header["n_images"] == [3] and header["features"] == "intensity_stats"
    arrays = learned.learned.to_arrays()
    assert set(stored) == set(arrays)
    for name, a in arrays.items():
        np.testing.assert_array_equal(stored[name], a)


def test_an_array_the_model_adds_needs_no_format_change(toy_stacks, tmp_path, monkeypatch):
    """The file stores whatever `to_arrays` returns and gives `from_arrays` all of it back: a
    model that adds an array (e.g. another head) round-trips without a change here."""
    seen = {}
    original_to, original_from = LearnedModel.to_arrays, LearnedModel.from_arrays.__func__

    def to_arrays(self):
        return {**original_to(self), "extra_head_W": np.arange(6.0).reshape(2, 3)}

    def from_arrays(cls, arrays):
        seen.update(arrays)
        return original_from(cls, arrays)

    monkeypatch.setattr(LearnedModel, "to_arrays", to_arrays)
    monkeypatch.setattr(LearnedModel, "from_arrays", classmethod(from_arrays))
    TrainedArtifact.from_learned(learned_model(), noise=None).save(tmp_path / "l.npz")
    TrainedArtifact.load(tmp_path / "l.npz")
    np.testing.assert_array_equal(seen["extra_head_W"], np.arange(6.0).reshape(2, 3))


def test_an_on_off_model_keeps_exact_levels(tmp_path):
    art = TrainedArtifact.from_learned(learned_model(binary=True), noise=None)
    art.save(tmp_path / "b.npz")
    loaded = TrainedArtifact.load(tmp_path / "b.npz")
    assert set(np.unique(loaded.led_patterns)) == {0.0, 1.0}
    assert "learned on/off patterns" in loaded.describe()


def _with_array(src, dst, name, value):
    with np.load(src, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    if value is None:
        del arrays[name]
    else:
        arrays[name] = value
    np.savez(dst, **arrays)


@pytest.mark.parametrize("name, value, message", [
    ("learned_layer0_W", "nan", "array 'learned_layer0_W' holds values that are not finite"),
    ("learned_feature_mean", "inf", "array 'learned_feature_mean' holds values that are not finite"),
    ("learned_feature_scale", "zero", "feature_scale must be > 0"),
    ("learned_patterns", "over", "LED levels must lie in [0, 1]"),
    ("learned_patterns", "rows", "learned model array 'patterns' must be (32, k)"),
    ("learned_patterns", None, "header field 'mode' is 'learned' but it has no array 'learned_patterns'"),
    ("learned_layer1_b", None, "learned model arrays"),
    ("learned_layer0_W", "text", "array 'learned_layer0_W' holds <U"),
    ("learned_class_names", "swapped", "the learned model's class names"),
    ("led_patterns", "other", "led_patterns differ from the learned model's patterns"),
])
def test_bad_learned_arrays_are_refused_naming_them(learned, tmp_path, name, value, message):
    learned.save(tmp_path / "a.npz")
    with np.load(tmp_path / "a.npz") as npz:
        a = npz[name].copy() if name in npz.files else None
    bad = {"nan": lambda: np.where(np.arange(a.size).reshape(a.shape) == 1, np.nan, a),
           "inf": lambda: np.where(np.arange(a.size) == 0, np.inf, a),
           "zero": lambda: np.where(np.arange(a.size) == 2, 0, a),
           "over": lambda: a + 1,
           "rows": lambda: a[:8],
           "text": lambda: a.astype(str),
           "swapped": lambda: a[::-1],
           "other": lambda: 1 - a,
           None: lambda: None}[value]()
    _with_array(tmp_path / "a.npz", tmp_path / "b.npz", name, bad)
    with pytest.raises(ArtifactError, match=re.escape(message)):
        TrainedArtifact.load(tmp_path / "b.npz")


@pytest.mark.parametrize("field, value, message", [
    ("n_images", [2], "header field 'n_images' must be [3], the learned model's image count"),
    ("features", "hog_grid", "a learned model classifies with 'intensity_stats' features"),
    ("format_version", 3, "header field 'mode' is 'learned', which format version 3 does not have"),
    ("mode", "joint", "it has no array 'coef_3'"),
])
def test_learned_header_fields_are_checked(learned, tmp_path, field, value, message):
    learned.save(tmp_path / "a.npz")
    rewrite_artifact(tmp_path / "a.npz", tmp_path / "b.npz", change_header=lambda h: h.update({field: value}))
    with pytest.raises(ArtifactError, match=re.escape(message)):
        TrainedArtifact.load(tmp_path / "b.npz")


def test_a_learned_mode_goes_with_a_learned_model_only(toy_stacks):
    from mux_classifier.estimator import MuxClassifier
    stacks, y = toy_stacks
    clf = MuxClassifier().fit(stacks[:, :1], y)
    with pytest.raises(ArtifactError, match="mode 'learned' without a learned model"):
        TrainedArtifact.from_classifiers([clf], np.ones((32, 1)), mode="learned")
    with pytest.raises(ArtifactError, match="mode 'joint' with a learned model"):
        TrainedArtifact(None, NAMES, [], mode="joint", features="intensity_stats",
                        learned=learned_model())


@pytest.fixture(scope="module")
def learned_bytes(learned, tmp_path_factory):
    return saved_bytes(learned, tmp_path_factory)


@FUZZ_SETTINGS
@given(data=st.data())
def test_fuzz_malformed_learned_files_raise_only_artifact_error(learned_bytes, tmp_path_factory, data):
    """The loader's fuzz test (test_artifact.py) on a learned artifact's file."""
    path = tmp_path_factory.getbasetemp() / "fuzzed_learned.npz"
    path.write_bytes(data.draw(mutated_artifacts(learned_bytes)))
    check_refused_or_classifies(path)


def test_fuzz_every_learned_header_field_out_of_range_is_refused_naming_it(learned, tmp_path):
    check_header_fields_refused_naming_them(learned, tmp_path)


def test_a_model_with_cross_image_statistics_round_trips(toy_stacks, tmp_path):
    stacks, _ = toy_stacks
    base = learned_model(stacks=stacks)
    k = base.n_images
    n_in = k * 9 + 2 * k * (k - 1) // 2
    rng = np.random.default_rng(5)
    with_ratio = LearnedModel(base.patterns, np.zeros(n_in), np.ones(n_in),
                              [(rng.normal(0, 1, (n_in, len(NAMES))), np.zeros(len(NAMES)))],
                              NAMES, ratio_offset=8.0)
    assert with_ratio.n_features == n_in and with_ratio.features(stacks).shape == (len(stacks), n_in)
    TrainedArtifact.from_learned(with_ratio, noise=SIGMA3).save(tmp_path / "r.npz")
    # format 5: a release that reads 4 refuses it by its version, not by a feature count
    with np.load(tmp_path / "r.npz", allow_pickle=False) as npz:
        assert json.loads(npz["header"].tobytes().decode())["format_version"] == 5 < FORMAT_VERSION
    loaded = TrainedArtifact.load(tmp_path / "r.npz")
    assert loaded.learned.ratio_offset == 8.0
    assert "intensity_stats + cross-image relief features" in loaded.describe()
    np.testing.assert_allclose(loaded.decision_function(stacks),
                               with_ratio.logits_from_features(with_ratio.features(stacks)), rtol=1e-6)
    # a model without them stores no offset (older releases read it as before)
    assert "ratio_offset" not in base.to_arrays()
    assert LearnedModel.from_arrays(base.to_arrays()).ratio_offset == 0.0
    with pytest.raises(ValueError, match="cross-image"):
        LearnedModel(base.patterns, base.feature_mean, base.feature_scale, base.layers, NAMES,
                     ratio_offset=8.0)
    with pytest.raises(ValueError, match="ratio_offset"):
        LearnedModel(base.patterns, base.feature_mean, base.feature_scale, base.layers, NAMES,
                     ratio_offset=-1.0)


def test_a_head_gated_by_type_round_trips_and_its_scores_pick_its_class(toy_stacks, tmp_path):
    stacks, _ = toy_stacks
    base = learned_model(stacks=stacks)
    groups = np.array([0, 0, 1, 1])   # apple_real, apple_fake | lime_real, lime_fake
    rng = np.random.default_rng(6)
    n_in = base.n_features
    gated = LearnedModel(base.patterns, base.feature_mean, base.feature_scale,
                         [(rng.normal(0, 1, (n_in, 2 + 4)), rng.normal(0, 0.1, 2 + 4))], NAMES,
                         class_groups=groups)
    assert gated.n_groups == 2 and gated.n_classes == 4
    TrainedArtifact.from_learned(gated, noise=SIGMA3).save(tmp_path / "g.npz")
    # format 6: a release that reads 5 refuses it by its version
    with np.load(tmp_path / "g.npz", allow_pickle=False) as npz:
        assert json.loads(npz["header"].tobytes().decode())["format_version"] == 6 == GROUPS_SINCE
    loaded = TrainedArtifact.load(tmp_path / "g.npz")
    np.testing.assert_array_equal(loaded.learned.class_groups, groups)
    assert "gated by object type" in loaded.describe()
    out = gated.logits_from_features(gated.features(stacks))
    # the class is the best class of the best type
    best_type = out[:, :2].argmax(axis=1)
    within = out[:, 2:].reshape(-1, 2, 2)[np.arange(len(out)), best_type]
    expected = 2 * best_type + within.argmax(axis=1)
    assert len(set(expected)) > 1   # the toy stacks reach more than one class
    scores = loaded.decision_function(stacks)
    np.testing.assert_array_equal(scores.argmax(axis=1), expected)
    np.testing.assert_array_equal(loaded.predict(stacks), np.asarray(NAMES)[expected])
    # positive for the class picked, negative for every other
    assert (scores[np.arange(len(scores)), expected] > 0).all()
    assert (np.sort(scores, axis=1)[:, -2] < 0).all()
    # a model without groups stores none
    assert "class_groups" not in base.to_arrays()
    assert LearnedModel.from_arrays(base.to_arrays()).class_groups is None


@pytest.mark.parametrize("groups, message", [
    (np.array([0, 0, 1]), "then the 3 classes: its last layer needs 5 outputs, got 6"),
    (np.array([0, 0, 2, 2]), "numbers the types|number the types"),
    (np.array([0.0, 0.0, 1.0, 1.0]), "integer"),
    (np.array([0, 0, 1, 10 ** 15]), "number the types"),
])
def test_bad_class_groups_are_refused(toy_stacks, groups, message):
    base = learned_model(stacks=toy_stacks[0])
    rng = np.random.default_rng(6)
    layers = [(rng.normal(0, 1, (base.n_features, 6)), np.zeros(6))]
    with pytest.raises(ValueError, match=message):
        LearnedModel(base.patterns, base.feature_mean, base.feature_scale, layers, NAMES,
                     class_groups=groups)


def test_a_gated_model_with_the_wrong_output_count_is_refused(toy_stacks):
    base = learned_model(stacks=toy_stacks[0])
    with pytest.raises(ValueError, match="needs 6 outputs, got 4"):
        LearnedModel(base.patterns, base.feature_mean, base.feature_scale, base.layers, NAMES,
                     class_groups=np.array([0, 0, 1, 1]))
