"""Checks shared by the artifact tests of every format (tests/mux_classifier/test_artifact.py,
test_learned_artifact.py): a file rewritten with a changed header, the fuzz settings, and
the rule every malformed file must meet (refused with ArtifactError naming what is wrong, or
loaded and classifying)."""
from __future__ import annotations

import json
import math
import os

import numpy as np
from hypothesis import HealthCheck, settings

from mux_classifier.artifact import ArtifactError, TrainedArtifact

SIGMA3 = {"name": "sigma3", "sigma_p2": 0.94, "sigma_r2": 117.37, "gain_db": 17.5,
          "exposure_ms": 22.5}


def rewrite_artifact(src, dst, change_header=None, drop=()):
    with np.load(src, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files if k not in drop}
    if change_header:
        header = json.loads(arrays["header"].tobytes().decode())
        change_header(header)
        arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(dst, **arrays)


def saved_bytes(artifact, tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("fuzz") / "a.npz"
    artifact.save(path)
    return path.read_bytes()


FUZZ_SETTINGS = settings(max_examples=int(os.environ.get("LIGHTSTAGE_FUZZ_EXAMPLES", 150)),
                         deadline=None,
                         suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def check_refused_or_classifies(path):
    """The file at `path` raises ArtifactError with a message, or loads and classifies."""
    try:
        loaded = TrainedArtifact.load(path)
    except ArtifactError as exc:
        assert str(exc)
        return
    size = loaded.hog_config.image_size
    prediction = loaded.predict_stack(np.zeros((loaded.n_images[-1], size, size), np.float32))
    assert prediction.label in loaded.class_names


BAD_HEADER_VALUES = [math.nan, math.inf, -math.inf, -1, -1e6, 0, 1e6, 1e300, 10**12, -(10**12),
                     "text", "", True, False, None, [], [1, 2, 3], [math.nan], {"x": 1}]


def header_fields(header: dict) -> list[tuple[str, ...]]:
    """Every field of the header: top level, and each key of the noise setting and HOG
    configuration."""
    fields = []
    for key, value in header.items():
        fields.append((key,))
        if isinstance(value, dict) and key != "provenance":
            fields += [(key, sub) for sub in value]
    return fields


def check_header_fields_refused_naming_them(artifact, tmp_path):
    """`test_fuzz_every_header_field_out_of_range_is_refused_naming_it` for `artifact`."""
    artifact.save(tmp_path / "a.npz")
    with np.load(tmp_path / "a.npz") as npz:
        header = json.loads(npz["header"].tobytes().decode())
    checked, unnamed = 0, []
    for path in header_fields(header):
        for value in BAD_HEADER_VALUES:
            def change(h, path=path, value=value):
                target = h
                for key in path[:-1]:
                    target = target[key]
                target[path[-1]] = value
            rewrite_artifact(tmp_path / "a.npz", tmp_path / "b.npz", change_header=change)
            try:
                loaded = TrainedArtifact.load(tmp_path / "b.npz")
            except ArtifactError as exc:
                if path[-1] not in str(exc):
                    unnamed.append((path, value, str(exc).split(" file: ", 1)[-1]))
                checked += 1
                continue
            size = loaded.hog_config.image_size
            images = np.zeros((loaded.n_images[-1], size, size), np.float32)
            assert loaded.predict_stack(images).label in loaded.class_names, (path, value)
    assert not unnamed, "\n".join(map(str, unnamed))
    assert checked > len(header_fields(header)) * len(BAD_HEADER_VALUES) // 2
