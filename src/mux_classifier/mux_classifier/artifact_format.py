"""The trained-classifier file: a versioned ``.npz`` (docs/CLASSIFIER.md, "Artifact format").

The metadata is a JSON document stored as a uint8 array (the header); the patterns and the
linear classifiers are plain numeric arrays. Files are read with ``allow_pickle=False``, so
opening one never runs code, and anything malformed raises `ArtifactError` naming what is
wrong. `write_artifact` / `read_artifact` are the only ways in and out; what the fields mean
and how they are validated is the data model's (`artifact.TrainedArtifact`).
"""
from __future__ import annotations

import io
import json
import math
import os
import reprlib
import secrets
import stat
import zipfile

import numpy as np
from lightstage_physics.noise import check_noise_coefficients
from lightstage_physics.rig import DEFAULT_DIMMER
from lightstage_graph.limits import DIMMER_MAX, DIMMER_MIN, LimitError, check_range

from .features import DEFAULT_EXTRACTOR, searchable_extractor
from .hog import HogConfig
from .novelty import ARRAY_NAMES as NOVELTY_ARRAYS
from .novelty import NOVELTY_FEATURES

__all__ = ["ArtifactError", "FORMAT_NAME", "FORMAT_VERSION", "READABLE_VERSIONS",
           "UNRECORDED_DIMMER", "MODES", "MAX_IMAGES", "LEARNED_MODE", "LEARNED_PREFIX",
           "read_artifact", "write_artifact", "written_version"]

FORMAT_NAME = "lightstage.mux_classifier"
# 7: the header carries "confidence" (calibrated probabilities and the anytime stop rule,
# `confidence.Confidence`) and/or "novelty" (the unknown-object models, `novelty`, their
# arrays "novelty_<k>_<name>"); a release that reads 6 would ignore them and answer without
# probabilities or "unknown", so such a file says 7. A file without either is still written
# as 4, 5 or 6.
# 6: a learned model whose head is gated by object type (its "learned_class_groups"): a
# release that reads 5 would take the types' scores for classes' and refuse the file as
# mis-sized, so such a file says 6.
# 5: a learned model with the cross-image statistics (its "learned_ratio_offset"): a
# release that reads 4 would take its features for the 9 per image and refuse or misread
# it, so such a file says 5. Every other file is still written as 4, which those read.
# 4: mode "learned": a learned-illumination model, every array of its `to_arrays()` stored
# as "learned_<name>" (new arrays of the model need no format change), no coef_/intercept_.
# 3: the header names the feature extractor ("features"); before, it was always the HOG grid.
# 2: the header records the dimmer the training rendered with. 1: it did not; every
# training that wrote version 1 rendered at the authors' dimmer, `UNRECORDED_DIMMER` (should
# DEFAULT_DIMMER ever change, this must keep its old value).
FORMAT_VERSION = 7   # the newest this release reads and writes
READABLE_VERSIONS = (1, 2, 3, 4, 5, 6, 7)
UNRECORDED_DIMMER = DEFAULT_DIMMER
LEARNED_MODE = "learned"
MODES = ("per_colour", "joint", "naive", LEARNED_MODE)
LEARNED_SINCE = 4  # the first format version with learned models
RATIO_SINCE = 5    # ... and with learned models' cross-image statistics
GROUPS_SINCE = 6   # ... and with learned models' heads gated by object type
CONFIDENCE_SINCE = 7  # ... and with calibrated probabilities and the anytime rule
NOVELTY_SINCE = 7     # ... and with the unknown-object (novelty) models
LEARNED_PREFIX = "learned_"
NOVELTY_PREFIX = "novelty_"
MAX_IMAGES = 4096  # images of one classification: far beyond any search (16 in the paper)
MAX_LEARNED_WIDTH = 4096  # hidden units of a learned model's layer (the trainer's: 0 .. 64)
DIMMER_RANGE = (DIMMER_MIN, DIMMER_MAX)


class ArtifactError(ValueError):
    """A trained-classifier file or its input is unusable; the message says why and what to do."""


def written_version(artifact) -> int:
    """The format version a file of `artifact` says: the lowest that holds it
    (`CONFIDENCE_SINCE` for a calibrated artifact, `GROUPS_SINCE`
    for a learned model gated by type, `RATIO_SINCE` for one with cross-image statistics,
    else `LEARNED_SINCE`), so that an older release refuses only what it would misread."""
    learned = artifact.learned
    if getattr(artifact, "confidence", None) is not None:
        return CONFIDENCE_SINCE
    if getattr(artifact, "novelty", None):
        return NOVELTY_SINCE
    if learned is not None and learned.class_groups is not None:
        return GROUPS_SINCE
    return RATIO_SINCE if learned is not None and learned.ratio_offset else LEARNED_SINCE


def _header(artifact) -> dict:
    return {
        "format": FORMAT_NAME,
        "format_version": written_version(artifact),
        "mode": artifact.mode,
        "class_names": artifact.class_names,
        "noise": artifact.noise,
        "hog_config": artifact.hog_config.to_dict(),
        "n_images": artifact.n_images,
        "has_site_patterns": artifact.site_patterns is not None,
        "provenance": artifact.provenance,
        "dimmer": artifact.dimmer,
        "features": artifact.features,
        **({"confidence": artifact.confidence.to_dict()}
           if getattr(artifact, "confidence", None) is not None else {}),
        **({"novelty": {"features": NOVELTY_FEATURES, "n_images": sorted(artifact.novelty)}}
           if getattr(artifact, "novelty", None) else {}),
    }


def write_artifact(path, artifact) -> None:
    """Write a (validated) TrainedArtifact to ``path`` in the current format; written to a
    temporary file first, then renamed."""
    try:
        header = json.dumps(_header(artifact), sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ArtifactError(f"provenance/noise must be plain JSON (no NaN): {exc}") from exc
    arrays = {"header": np.frombuffer(header.encode("utf-8"), dtype=np.uint8),
              "led_patterns": artifact.led_patterns}
    if artifact.site_patterns is not None:
        arrays["site_patterns"] = artifact.site_patterns
    for s in artifact.stages:
        arrays[f"coef_{s.n_images}"] = s.coef
        arrays[f"intercept_{s.n_images}"] = s.intercept
    if artifact.learned is not None:
        for name, a in artifact.learned.to_arrays().items():
            arrays[LEARNED_PREFIX + name] = np.asarray(a)
    for k, model in sorted((getattr(artifact, "novelty", None) or {}).items()):
        for name, a in model.to_arrays().items():
            arrays[f"{NOVELTY_PREFIX}{k}_{name}"] = a
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    # a new file of its own ("x": never another's), created with the umask's mode as any
    # other file (mkstemp's 0600 would survive the rename: unreadable to other users)
    tmp = os.path.join(directory, f".artifact-{os.getpid()}-{secrets.token_hex(6)}.npz")
    fh = open(tmp, "xb")
    try:
        with fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def read_artifact(path, build):
    """``build(**fields)`` of the artifact file at ``path`` (any readable format version);
    never unpickles, never runs code.

    ``fields`` are TrainedArtifact's: led_patterns, class_names, stages (tuples n_images,
    coef, intercept), noise, hog_config, mode, site_patterns, provenance, dimmer,
    dimmer_recorded, features, learned (None, or a learned model's named arrays), confidence
    (None, or the calibration's dict), novelty (None, or {image count: named arrays}). Whatever else ``path`` holds (nothing, a directory, another
    kind of file, an archive whose members are not .npy arrays, a malformed header or
    arrays), and any ArtifactError of ``build``, raises ArtifactError saying what is wrong.
    """
    path = os.fspath(path)
    what = f"{path!r} is not a readable lightstage classifier file"
    arrays = _read_npz(path, what)
    header = _read_header(arrays, what)
    version = header.get("format_version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise ArtifactError(
            f"{path!r}: its header field 'format_version' gives classifier format version "
            f"{reprlib.repr(version)}; this lightstage "
            f"reads version {FORMAT_VERSION} and the older "
            f"{', '.join(str(v) for v in READABLE_VERSIONS if v != FORMAT_VERSION)}. "
            "Retrain with this version (`lightstage train`) or use the lightstage release "
            "that wrote it")
    try:
        return build(**_fields(header, arrays))
    except ArtifactError as exc:
        raise ArtifactError(f"{what}: {exc}") from None
    except Exception as exc:  # whatever else a malformed file trips over
        raise ArtifactError(f"{what}: malformed content ({type(exc).__name__}: {exc}); "
                            "retrain to get a new file") from exc


def _fields(header: dict, arrays: dict) -> dict:
    """The artifact's fields from a file's header and arrays, by the header's version."""
    def field_of(key, kind, description):
        value = header.get(key)
        if not isinstance(value, kind):
            raise ArtifactError(f"header field {key!r} must be {description}, got "
                                f"{reprlib.repr(value)}")
        return value

    def array(name):
        if name not in arrays:
            raise ArtifactError(f"it has no array {name!r}; retrain to get a new file")
        a = arrays[name]
        if a.dtype.kind not in "biuf":
            raise ArtifactError(f"array {name!r} holds {a.dtype} values, not real numbers")
        return a

    _check_header_ranges(header)
    n_images = field_of("n_images", list, "a list of image counts")
    if not all(isinstance(k, int) and not isinstance(k, bool) for k in n_images):
        raise ArtifactError(f"header field 'n_images' must list integers, got "
                            f"{reprlib.repr(n_images)}")
    class_names = field_of("class_names", list, "a list of class names")
    if not all(isinstance(c, str) for c in class_names):
        raise ArtifactError(f"header field 'class_names' must list strings, got "
                            f"{reprlib.repr(class_names)}")
    if header["format_version"] == 1:  # before the dimmer was recorded
        dimmer, recorded = UNRECORDED_DIMMER, False
    else:  # a number here; the data model refuses booleans and values <= 0
        dimmer, recorded = field_of("dimmer", (int, float), "a positive number"), True
    features = (field_of("features", str, "the name of a feature extractor")
                if header["format_version"] >= 3 else DEFAULT_EXTRACTOR)
    mode = field_of("mode", str, f"one of {MODES}")
    learned = None
    if mode == LEARNED_MODE:
        learned = _learned_arrays(arrays)
        k = learned["patterns"].shape[1] if learned["patterns"].ndim == 2 else None
        if n_images != [k]:
            raise ArtifactError(f"header field 'n_images' must be [{k}], the learned model's "
                                f"image count, got {reprlib.repr(n_images)}")
    return dict(
        led_patterns=array("led_patterns"),
        class_names=class_names,
        stages=([] if learned is not None else
                [(k, array(f"coef_{k}"), array(f"intercept_{k}")) for k in n_images]),
        noise=field_of("noise", dict, "an object (the noise setting)"),
        hog_config=HogConfig.from_dict(field_of("hog_config", dict, "an object")),
        mode=mode,
        site_patterns=(_site_patterns(arrays, array)
                       if field_of("has_site_patterns", bool, "true or false") else None),
        provenance=dict(field_of("provenance", (dict, type(None)), "an object") or {}),
        dimmer=dimmer,
        dimmer_recorded=recorded,
        features=features,
        learned=learned,
        confidence=(field_of("confidence", dict, "an object (the calibration)")
                    if header["format_version"] >= CONFIDENCE_SINCE and "confidence" in header
                    else None),
        novelty=(_novelty_arrays(field_of("novelty", dict, "an object (the novelty models)"),
                                 arrays, array)
                 if header["format_version"] >= NOVELTY_SINCE and "novelty" in header else None),
    )


def _novelty_arrays(doc: dict, arrays: dict, array) -> dict:
    """{image count: the novelty model's named arrays} of the header's "novelty" entry."""
    unknown = sorted(set(doc) - {"features", "n_images"})
    if unknown:
        raise ArtifactError(f"header field 'novelty' has unknown keys {unknown}")
    if doc.get("features") != NOVELTY_FEATURES:
        raise ArtifactError(f"header field 'novelty.features' must be {NOVELTY_FEATURES!r} "
                            f"(the features this release scores novelty on), got "
                            f"{reprlib.repr(doc.get('features'))}")
    counts = doc.get("n_images")
    if not isinstance(counts, list) or not counts or not all(
            isinstance(k, int) and not isinstance(k, bool) and 1 <= k <= MAX_IMAGES
            for k in counts) or len(set(counts)) != len(counts):
        raise ArtifactError(f"header field 'novelty.n_images' must list distinct image "
                            f"counts 1 .. {MAX_IMAGES}, got {reprlib.repr(counts)}")
    return {k: {name: array(f"{NOVELTY_PREFIX}{k}_{name}") for name in NOVELTY_ARRAYS}
            for k in counts}


def _learned_arrays(arrays: dict) -> dict:
    """The learned model's arrays ("learned_<name>" -> name), each of real numbers (its
    class names: text) and finite; ArtifactError naming the first that is not."""
    found = {name[len(LEARNED_PREFIX):]: a for name, a in arrays.items()
             if name.startswith(LEARNED_PREFIX)}
    if "patterns" not in found:
        raise ArtifactError(f"header field 'mode' is {LEARNED_MODE!r} but it has no array "
                            f"'{LEARNED_PREFIX}patterns'; retrain to get a new file")
    for name, a in found.items():
        member = LEARNED_PREFIX + name
        if name == "class_names":
            if a.dtype.kind != "U" or a.ndim != 1:
                raise ArtifactError(f"array {member!r} must be a 1-D array of text, got "
                                    f"{a.dtype} of shape {a.shape}")
            continue
        if a.dtype.kind not in "biuf":
            raise ArtifactError(f"array {member!r} holds {a.dtype} values, not real numbers")
        with np.errstate(over="ignore"):
            finite = np.isfinite(a.astype(np.float32)).all()
        if not finite:
            raise ArtifactError(f"array {member!r} holds values that are not finite float32 "
                                "numbers; retrain to get a new file")
    return found


def _site_patterns(arrays: dict, array) -> np.ndarray:
    if "site_patterns" not in arrays:
        raise ArtifactError("header field 'has_site_patterns' is true but it has no array "
                            "'site_patterns'; retrain to get a new file")
    return array("site_patterns")



# An artifact is read whole into memory and its members inflated: an untrusted file is bounded
# before either. Trained artifacts are far below these (the demo's: well under 1 MB; a
# learned model's largest layer, MAX_LEARNED_WIDTH^2 float64, is 128 MiB); a 1 MB file whose
# member inflated to 1 GiB took the classifier node from 311 MB to 2.6 GB before it was
# refused, and under a memory limit a bare MemoryError escaped.
MAX_ARTIFACT_FILE_BYTES = 256 * 2**20
MAX_ARTIFACT_ARRAY_BYTES = 256 * 2**20  # all members' arrays together, as their headers declare
MAX_ARTIFACT_MEMBERS = 4096


def _mib(n: int) -> str:
    return f"{n / 2**20:.0f} MiB"


def _check_npz_budget(data: bytes, path: str, what: str) -> None:
    """Refuse, before anything is inflated, an archive whose members' declared sizes, or
    whose arrays' declared shapes, exceed the budget (MAX_ARTIFACT_*), naming the file and
    the limit. Only the members' .npy headers are read. The zip reader stops a member at its
    declared size (a longer stream fails its CRC), and numpy allocates a member's array from
    its header's shape, so these two bound what loading allocates."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            members = archive.infolist()
            if len(members) > MAX_ARTIFACT_MEMBERS:
                raise ArtifactError(f"{what}: it has {len(members)} members, more than the "
                                    f"{MAX_ARTIFACT_MEMBERS} an artifact may have")
            declared = sum(m.file_size for m in members)
            if declared > MAX_ARTIFACT_ARRAY_BYTES:
                raise ArtifactError(
                    f"{what}: its members would inflate to {_mib(declared)}, beyond the "
                    f"{_mib(MAX_ARTIFACT_ARRAY_BYTES)} limit of an artifact (refused before "
                    "inflating; a trained artifact is far smaller): retrain to get a new file")
            total = 0
            for member in members:
                if not member.filename.endswith(".npy"):
                    continue  # np.load hands it back as bytes; refused below as not an array
                with archive.open(member) as fp:
                    if fp.read(len(np.lib.format.MAGIC_PREFIX)) != np.lib.format.MAGIC_PREFIX:
                        continue  # not an .npy: np.load hands it back as bytes, refused below
                    version = tuple(fp.read(2))
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(fp)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(fp)
                    else:
                        raise ArtifactError(f"{what}: member {member.filename!r} is an .npy "
                                            f"file of version {version}, not 1.0 or 2.0")
                count = 1
                for n in shape:
                    count *= int(n)
                total += count * dtype.itemsize
                if total > MAX_ARTIFACT_ARRAY_BYTES:
                    raise ArtifactError(
                        f"{what}: its arrays declare {_mib(total)} or more (member "
                        f"{member.filename!r}: shape {reprlib.repr(shape)} of {dtype}), beyond "
                        f"the {_mib(MAX_ARTIFACT_ARRAY_BYTES)} limit of an artifact (refused "
                        "before allocating): retrain to get a new file")
    except ArtifactError:
        raise
    except Exception as exc:  # noqa: BLE001 - bad headers, truncated members, bad zip structure
        raise ArtifactError(f"{what}: {type(exc).__name__}: {exc}; retrain to get a new "
                            "file") from None


def _read_npz(path: str, what: str) -> dict:
    """The arrays of the .npz at ``path``; ArtifactError for anything else, a file or arrays
    beyond the budget (MAX_ARTIFACT_*) among it, before they are read or inflated."""
    try:
        st = os.stat(path)
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        raise ArtifactError(f"cannot read classifier file {path!r}: {exc}") from exc
    if not stat.S_ISREG(st.st_mode):  # a directory, a device (endless), a pipe (blocks)
        raise ArtifactError(f"{path!r} is not a regular file; point to the .npz written by "
                            "`lightstage train`")
    if st.st_size > MAX_ARTIFACT_FILE_BYTES:
        raise ArtifactError(f"{what}: it is {_mib(st.st_size)}, beyond the "
                            f"{_mib(MAX_ARTIFACT_FILE_BYTES)} limit of an artifact file (a "
                            "trained artifact is far smaller)")
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_ARTIFACT_FILE_BYTES + 1)
    except (OSError, MemoryError) as exc:
        raise ArtifactError(f"cannot read classifier file {path!r}: {type(exc).__name__}: "
                            f"{exc}") from None
    if len(data) > MAX_ARTIFACT_FILE_BYTES:  # grew since the stat
        raise ArtifactError(f"{what}: it is beyond the {_mib(MAX_ARTIFACT_FILE_BYTES)} limit "
                            "of an artifact file")
    if not zipfile.is_zipfile(io.BytesIO(data)):
        raise ArtifactError(
            f"{what}: it is not an .npz archive (truncated, or another kind of file); "
            "point to the .npz written by `lightstage train`, or retrain")
    _check_npz_budget(data, path, what)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except Exception as exc:  # corrupt members, pickled object arrays, bad CRC ...
        raise ArtifactError(f"{what}: {type(exc).__name__}: {exc}; retrain to get a new file") from exc
    # np.load hands a member that is not an .npy file back as its raw bytes
    not_arrays = sorted(name for name, a in arrays.items() if not isinstance(a, np.ndarray))
    if not_arrays:
        raise ArtifactError(f"{what}: its members {not_arrays} are not .npy arrays; retrain to "
                            "get a new file")
    return arrays


# The range of every header field the loader reads, beyond its type: (lo, hi) of a number, or
# of a list's length / a string's length. A field out of range is refused naming it.
MAX_CLASSES = 10_000
MAX_NAME_CHARS = 200
HOG_RANGES = {"image_size": (4, 2048), "cell_px": (1, 2048), "block_cells": (1, 2048),
              "orientations": (1, 360), "batch_size": (1, 4096)}


def _non_finite_field(value, path: str = "") -> str | None:
    """The path ('noise.gain_db', 'n_images[2]') of the first NaN or infinite number in a
    parsed header, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return path
    children = (value.items() if isinstance(value, dict)
                else enumerate(value) if isinstance(value, list) else ())
    for key, child in children:
        where = f"{path}[{key}]" if isinstance(key, int) else (f"{path}.{key}" if path else str(key))
        found = _non_finite_field(child, where)
        if found is not None:
            return found
    return None


def _check_header_ranges(header: dict) -> None:
    """Refuse, naming the field, a header value out of its range (the types are checked where
    each field is read; NaN and inf are refused by `_read_header`): the noise setting's coefficients,
    gain and exposure, the dimmer, the HOG configuration, the class names and image counts."""
    def within(path, value, lo, hi, unit=""):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                check_range(value, f"header field {path!r}", lo, hi, unit)
            except LimitError as exc:
                raise ArtifactError(str(exc)) from None

    noise = header.get("noise")
    if isinstance(noise, dict):
        unknown = sorted(set(noise) - {"name", "sigma_p2", "sigma_r2", "gain_db", "exposure_ms"})
        if unknown:
            raise ArtifactError(f"header field 'noise' has unknown keys {unknown}")
        if not isinstance(noise.get("name"), str):
            raise ArtifactError(f"header field 'noise.name' must be a string, got "
                                f"{reprlib.repr(noise.get('name'))}")
        for key in ("sigma_p2", "sigma_r2", "gain_db", "exposure_ms"):
            value = noise.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise ArtifactError(f"header field 'noise.{key}' must be a number or null, got "
                                    f"{reprlib.repr(value)}")
        if all(isinstance(noise.get(k), (int, float)) for k in ("sigma_p2", "sigma_r2", "gain_db",
                                                                "exposure_ms")):
            try:
                check_noise_coefficients(noise["sigma_p2"], noise["sigma_r2"], noise["gain_db"],
                                         noise["exposure_ms"], what="header field 'noise.{}'")
            except ValueError as exc:
                raise ArtifactError(str(exc)) from None
    hog = header.get("hog_config")
    if isinstance(hog, dict):
        unknown = sorted(set(hog) - set(HogConfig.__dataclass_fields__))
        if unknown:
            raise ArtifactError(f"header field 'hog_config' has unknown keys {unknown}")
        for key, (lo, hi) in HOG_RANGES.items():
            value = hog.get(key)
            if key in hog and (isinstance(value, bool) or not isinstance(value, int)):
                raise ArtifactError(f"header field 'hog_config.{key}' must be a whole number in "
                                    f"{lo} .. {hi}, got {reprlib.repr(value)}")
            within(f"hog_config.{key}", value, lo, hi)
    if "dimmer" in header:
        within("dimmer", header["dimmer"], DIMMER_RANGE[0], DIMMER_RANGE[1])
    names = header.get("class_names")
    if isinstance(names, list):
        if not 2 <= len(names) <= MAX_CLASSES:
            raise ArtifactError(f"header field 'class_names' must list 2 .. {MAX_CLASSES} "
                                f"classes, got {len(names)}")
        for i, name in enumerate(names):
            if isinstance(name, str) and not 1 <= len(name) <= MAX_NAME_CHARS:
                raise ArtifactError(f"header field 'class_names[{i}]' must be 1 .. "
                                    f"{MAX_NAME_CHARS} characters, got {reprlib.repr(name)}")
    counts = header.get("n_images")
    if isinstance(counts, list):
        if not counts:
            raise ArtifactError("header field 'n_images' lists no image count; the artifact "
                                "holds no classifier")
        for i, k in enumerate(counts):
            within(f"n_images[{i}]", k, 1, MAX_IMAGES)
    features = header.get("features")
    if isinstance(features, str):
        try:
            searchable_extractor(features)
        except ValueError as exc:
            raise ArtifactError(f"header field 'features': {exc}") from None
    mode = header.get("mode")
    if isinstance(mode, str) and mode not in MODES:
        raise ArtifactError(f"header field 'mode' must be one of {MODES}, got {reprlib.repr(mode)}")
    version = header.get("format_version")
    if mode == LEARNED_MODE and isinstance(version, int) and version < LEARNED_SINCE:
        raise ArtifactError(f"header field 'mode' is {LEARNED_MODE!r}, which format version "
                            f"{version} does not have (learned models since version "
                            f"{LEARNED_SINCE})")


def _json_number(text: str) -> float:
    return float(text)  # 1e400 is inf: refused naming its field (_check_header_ranges)


def _json_constant(name: str) -> float:
    return float(name.replace("Infinity", "inf"))  # NaN, Infinity: refused naming the field


def _read_header(arrays: dict, what: str) -> dict:
    """The artifact's JSON header (format name checked); ArtifactError if there is none."""
    if "header" not in arrays:
        raise ArtifactError(f"{what}: it has no header (an .npz from something else?)")
    raw = arrays["header"]
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise ArtifactError(f"{what}: its header is a {raw.dtype} array of shape {raw.shape}, "
                            "not the bytes of a JSON document (uint8, 1-D)")
    try:
        header = json.loads(raw.tobytes().decode("utf-8"), parse_float=_json_number,
                            parse_constant=_json_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ArtifactError(f"{what}: its header is not valid JSON ({exc})") from exc
    found = header.get("format") if isinstance(header, dict) else header
    if found != FORMAT_NAME or not isinstance(header, dict):
        raise ArtifactError(f"{what}: header format is {reprlib.repr(found)}, expected "
                            f"{FORMAT_NAME!r}")
    bad = _non_finite_field(header)
    if bad is not None:
        raise ArtifactError(f"{what}: its header field {bad!r} is not a finite number (NaN, "
                            "infinite or beyond a float); retrain to get a new file")
    return header

