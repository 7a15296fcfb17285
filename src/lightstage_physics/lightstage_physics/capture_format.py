"""The capture folder: how relightable models are stored on disk (docs/CAPTURE_FORMAT.md).

    <root>/rig.yaml
    <root>/<label>/<sample>/<pose>/s<site>_<channel>.png

one 16-bit grayscale PNG per single LED (site 0..7, channel red|green|blue|nir), gray levels
MSB-aligned in 16 bits (a 10-bit value v is stored as v << 6; finer bits may carry the
extra precision of averaged frames). `load_capture` validates everything and keeps a
binary cache in `<root>/.cache/` that is rebuilt whenever a file changes.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
import zlib
from pathlib import Path

import numpy as np
from PIL import Image

from .errors import CaptureFormatError
from .rig import CHANNELS, Rig
from .scene_models import ModelSet, downscale_images

RIG_FILE = "rig.yaml"
CACHE_DIR = ".cache"
CACHE_VERSION = 2  # 2: the index holds the data's CRC-32
IMAGE_NAME = re.compile(r"^s(\d+)_([A-Za-z0-9]+)\.png$")


def image_name(site: int, channel: str) -> str:
    return f"s{site}_{channel}.png"


def _visible_dirs(path: Path) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))


def _scan(root: Path, rig: Rig) -> list[tuple[str, str, str, Path]]:
    """(label, sample, pose, pose_dir) for every pose folder, validating names and files."""
    entries = []
    labels = _visible_dirs(root)
    if not labels:
        raise CaptureFormatError(f"{root}: no label folders; expected "
                                 "<label>/<sample>/<pose>/s<site>_<channel>.png under it")
    expected = {image_name(s, c) for s in range(rig.n_sites) for c in CHANNELS}
    for label_dir in labels:
        samples = _visible_dirs(label_dir)
        if not samples:
            raise CaptureFormatError(f"{label_dir}: label folder holds no sample folders "
                                     "(expected <label>/<sample>/<pose>/)")
        for sample_dir in samples:
            poses = _visible_dirs(sample_dir)
            if not poses:
                raise CaptureFormatError(f"{sample_dir}: sample folder holds no pose folders")
            for pose_dir in poses:
                names = {p.name for p in pose_dir.iterdir() if p.suffix.lower() == ".png"}
                for name in sorted(names - expected):
                    match = IMAGE_NAME.match(name)
                    if not match:
                        problem = "is not named s<site>_<channel>.png"
                    elif match.group(2) not in CHANNELS:
                        problem = (f"has unknown channel '{match.group(2)}'; "
                                   f"channels are {', '.join(CHANNELS)}")
                    else:
                        problem = (f"names site {match.group(1)}, but rig.yaml has sites "
                                   f"0..{rig.n_sites - 1}")
                    raise CaptureFormatError(f"{pose_dir / name}: {problem}; rename or remove it")
                missing = sorted(expected - names)
                if missing:
                    more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
                    raise CaptureFormatError(
                        f"{pose_dir / missing[0]}: missing image{more}; every pose needs one "
                        f"16-bit PNG per site and channel ({len(expected)} files)")
                entries.append((label_dir.name, sample_dir.name, pose_dir.name, pose_dir))
    return entries


def read_image(path: Path, rig: Rig) -> np.ndarray:
    """One single-LED image as its raw 16-bit values, validated against the rig."""
    try:
        with Image.open(path) as im:
            mode = im.mode
            if mode not in ("I;16", "I;16B", "I;16L"):
                depth = {"1": "1-bit", "L": "8-bit gray", "P": "palette", "RGB": "RGB",
                         "RGBA": "RGBA", "I": "32-bit", "F": "float"}.get(mode, mode)
                raise CaptureFormatError(
                    f"{path}: image is {depth} (mode {mode}); expected 16-bit grayscale with "
                    f"gray levels MSB-aligned (a {rig.bit_depth}-bit value shifted left by "
                    f"{16 - rig.bit_depth})")
            data = np.asarray(im, dtype=np.uint16)
    except CaptureFormatError:
        raise
    except Exception as exc:  # Pillow raises several types for a broken file
        raise CaptureFormatError(f"{path}: cannot be read as a PNG ({exc})") from exc
    if data.shape != tuple(rig.image_size):
        raise CaptureFormatError(
            f"{path}: image is {data.shape[0]}x{data.shape[1]} (HxW) but rig.yaml says "
            f"{rig.image_size[0]}x{rig.image_size[1]}; fix the image or camera.image_height/width")
    return data


def _fingerprint(root: Path, entries, n_sites: int) -> str:
    h = hashlib.sha256()
    for path in [root / RIG_FILE] + [e[3] / image_name(s, c) for e in entries
                                      for s in range(n_sites) for c in CHANNELS]:
        st = path.stat()
        h.update(f"{path.relative_to(root)}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _load_rig(root: Path) -> Rig:
    rig_path = root / RIG_FILE
    if not rig_path.is_file():
        raise CaptureFormatError(f"{rig_path}: missing; every capture folder needs a rig.yaml "
                                 "(see docs/CAPTURE_FORMAT.md)")
    try:
        return Rig.load_yaml(rig_path)
    except CaptureFormatError:
        raise
    except Exception as exc:  # yaml errors, missing keys, bad values
        message = str(exc)
        if not message.startswith(str(rig_path)):
            message = f"{rig_path}: {message}"
        raise CaptureFormatError(message) from exc


def _metadata(entries) -> dict:
    class_names = sorted({e[0] for e in entries})
    sample_names, labels, pose_index, instance = [], [], [], []
    counters: dict[str, int] = {}
    n_samples: dict[str, int] = {}
    sample_ids: dict[tuple[str, str], int] = {}
    for label, sample, pose, _ in entries:  # entries are sorted label/sample/pose
        if (label, sample) not in sample_ids:
            sample_ids[(label, sample)] = n_samples.get(label, 0)
            n_samples[label] = sample_ids[(label, sample)] + 1
        sample_names.append(f"{label}/{sample}/{pose}")
        labels.append(class_names.index(label))
        pose_index.append(counters.get(label, 0))
        counters[label] = counters.get(label, 0) + 1
        instance.append(sample_ids[(label, sample)])
    return {"class_names": class_names, "sample_names": sample_names, "labels": labels,
            "pose_index": pose_index, "instance": instance}


def _to_gray(raw: np.ndarray, rig: Rig, downscale_to, chunk: int = 8):
    """uint16 MSB-aligned raw -> float32 gray levels (optionally downscaled chunk by chunk)."""
    scale = np.float32(1.0 / (1 << (16 - rig.bit_depth)))
    if downscale_to is None:
        out = raw.astype(np.float32)
        out *= scale
        return out, 1.0
    parts, factor = [], 1.0
    for i in range(0, len(raw), chunk):
        part = raw[i:i + chunk].astype(np.float32)
        part *= scale
        small, factor = downscale_images(part, downscale_to)
        parts.append(small)
    return np.concatenate(parts) if parts else np.zeros((0,), np.float32), factor


def load_capture(path, cache: bool = True, downscale_to: int | None = None) -> ModelSet:
    """Load and validate a capture folder as a ModelSet (gray levels in camera units).

    `cache` reuses/refreshes `<path>/.cache/` (raw 16-bit arrays + index); it is keyed on
    every file's name, size and modification time. `downscale_to` (e.g. 120) returns the
    downscaled ModelSet without holding the full-resolution float array in memory.
    """
    root = Path(path)
    if not root.is_dir():
        raise CaptureFormatError(f"{root}: not a directory; give the capture folder that holds "
                                 "rig.yaml")
    rig = _load_rig(root)
    entries = _scan(root, rig)
    meta = _metadata(entries)
    fingerprint = _fingerprint(root, entries, rig.n_sites)
    cache_dir = root / CACHE_DIR
    raw = None
    if cache:
        raw = _read_cache(cache_dir, fingerprint, len(entries), rig)
    if raw is None:
        raw = np.empty((len(entries), len(CHANNELS), rig.n_sites, *rig.image_size), np.uint16)
        for i, (_, _, _, pose_dir) in enumerate(entries):
            for c, channel in enumerate(CHANNELS):
                for s in range(rig.n_sites):
                    raw[i, c, s] = read_image(pose_dir / image_name(s, channel), rig)
        if cache:
            _write_cache(cache_dir, fingerprint, raw)
    models, factor = _to_gray(raw, rig, downscale_to)
    del raw
    out_rig = rig
    if downscale_to is not None:
        from dataclasses import replace
        out_rig = replace(rig, image_size=models.shape[-2:])
    return ModelSet(models, np.array(meta["labels"]), meta["class_names"],
                    meta["sample_names"], np.array(meta["pose_index"]),
                    np.array(meta["instance"]), out_rig, noise_scale=factor)


def check_equal_poses(modelset: ModelSet, source="capture") -> None:
    """Refuse a ModelSet whose classes have different numbers of poses (CaptureFormatError).

    Training and evaluation split by pose index, the same indices in every class: with
    unequal counts a held-out index that only some classes have tests those classes alone,
    and a smaller class is tested on fewer poses (or none) than the others, so accuracies
    would not mean what they say. The loader itself allows it (a capture in progress).
    """
    counts = np.bincount(modelset.labels, minlength=len(modelset.class_names))
    if len(set(counts.tolist())) <= 1:
        return
    by_count: dict[int, list[str]] = {}
    for name, n in zip(modelset.class_names, counts.tolist()):
        by_count.setdefault(n, []).append(name)
    listed = "; ".join(f"{n} pose(s): {', '.join(names)}" for n, names in sorted(by_count.items()))
    raise CaptureFormatError(
        f"{source}: classes have different numbers of poses ({listed}); the pose splits hold "
        "out the same pose indices in every class, so every class needs the same number of "
        "poses (docs/CAPTURE_FORMAT.md): capture the missing poses, or move the extra pose "
        "folders out of the capture folder")


def _file_digest(path: Path) -> str:
    """CRC-32 of a file's bytes, read in blocks: it finds data changed in place (zeroed,
    corrupted on disk) at ~1.5 GB/s, twice SHA-256's speed here; the cache is a local
    copy, not guarded against someone forging it."""
    crc = 0
    with open(path, "rb") as fh:
        while block := fh.read(1 << 24):
            crc = zlib.crc32(block, crc)
    return f"{crc:08x}"


def _read_cache(cache_dir: Path, fingerprint: str, n: int, rig: Rig):
    """The cached raw images, or None to rebuild: the index must name these files (names,
    sizes, times) and the data must have the digest written with it -- a cache whose bytes
    changed with its size kept (zeroed, corrupted on disk) is not trusted."""
    index, data = cache_dir / "index.json", cache_dir / "models_u16.npy"
    try:
        info = json.loads(index.read_text())
        if info.get("version") != CACHE_VERSION or info.get("fingerprint") != fingerprint:
            return None
        if info.get("crc32") != _file_digest(data):
            return None
        # memory-mapped: a downscaling load then never holds the full-resolution set
        raw = np.load(data, allow_pickle=False, mmap_mode="r")
    except (OSError, ValueError, AttributeError):
        return None
    if raw.shape != (n, len(CHANNELS), rig.n_sites, *rig.image_size) or raw.dtype != np.uint16:
        return None
    return raw


def _write_cache(cache_dir: Path, fingerprint: str, raw: np.ndarray) -> None:
    try:
        cache_dir.mkdir(exist_ok=True)
        tmp = cache_dir / f"models_u16.{os.getpid()}.tmp.npy"
        np.save(tmp, raw, allow_pickle=False)
        digest = _file_digest(tmp)
        os.replace(tmp, cache_dir / "models_u16.npy")
        tmp_index = cache_dir / f"index.{os.getpid()}.tmp"
        tmp_index.write_text(json.dumps({"version": CACHE_VERSION, "fingerprint": fingerprint,
                                         "crc32": digest}))
        os.replace(tmp_index, cache_dir / "index.json")
    except OSError as exc:  # a read-only capture folder still loads, just without a cache
        warnings.warn(f"could not write the capture cache in {cache_dir}: {exc}")


# ---- writing --------------------------------------------------------------------------
def to_raw16(gray: np.ndarray, bit_depth: int) -> np.ndarray:
    """Gray levels in camera units -> MSB-aligned uint16 (rounded, clipped)."""
    shifted = np.rint(np.asarray(gray, dtype=np.float64) * (1 << (16 - bit_depth)))
    return np.clip(shifted, 0, 65535).astype(np.uint16)


def write_pose(pose_dir, model: np.ndarray, bit_depth: int = 10, compress_level: int = 6) -> None:
    """Write one pose's ``(4, sites, H, W)`` single-LED images (gray levels) as PNGs."""
    pose_dir = Path(pose_dir)
    pose_dir.mkdir(parents=True, exist_ok=True)
    raw = to_raw16(model, bit_depth)
    for c, channel in enumerate(CHANNELS):
        for s in range(raw.shape[1]):
            Image.fromarray(raw[c, s]).save(pose_dir / image_name(s, channel),
                                            compress_level=compress_level)


def pose_folder(sample_name: str, class_name: str, instance: int, pose_index: int) -> str:
    """Relative folder of a sample: its name if it is label/sample/pose, else built."""
    parts = sample_name.split("/")
    if len(parts) == 3 and parts[0] == class_name and all(parts):
        return sample_name
    return f"{class_name}/s{instance}/p{pose_index:02d}"


def write_capture(path, modelset, rig: Rig | None = None, compress_level: int = 6) -> Path:
    """Write a ModelSet (or a dict with its fields) as a capture folder; returns the path."""
    if isinstance(modelset, dict):
        fields = dict(modelset)
        n = len(fields["models"])
        fields.setdefault("pose_index", np.arange(n))
        fields.setdefault("instance", np.zeros(n, int))
        fields.setdefault("sample_names", [""] * n)
        rig = rig or fields.pop("rig", None)
        if rig is None:
            raise ValueError("write_capture needs a rig for raw arrays")
        modelset = ModelSet(rig=rig, **{k: fields[k] for k in (
            "models", "labels", "class_names", "sample_names", "pose_index", "instance")})
    rig = rig or modelset.rig
    if tuple(modelset.models.shape[-2:]) != tuple(rig.image_size):
        raise ValueError(f"models are {modelset.models.shape[-2:]} but the rig says "
                         f"{rig.image_size}; pass a rig with the models' image size")
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    rig.save_yaml(root / RIG_FILE)
    for i in range(len(modelset)):
        label = modelset.class_names[modelset.labels[i]]
        rel = pose_folder(modelset.sample_names[i], label, int(modelset.instance[i]),
                          int(modelset.pose_index[i]))
        write_pose(root / rel, modelset.models[i], rig.bit_depth, compress_level)
    return root
