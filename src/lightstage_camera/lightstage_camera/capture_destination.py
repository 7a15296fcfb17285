"""Writing one pose into a capture folder: names, rig.yaml agreement, atomic writes.

`check_destination` checks a pose can go into the folder (names usable as folder names,
a folder that takes files, a ``rig.yaml`` that agrees with this capture, no existing pose
unless asked); `write_model` writes it atomically: a staging folder under
``<root>/.staging/`` (ignored by the loader) renamed into place. The folder format itself
is `capture_format` (docs/CAPTURE_FORMAT.md).
"""
from __future__ import annotations

import math
import os
import re
import shutil
import uuid
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lightstage_physics.capture_format import RIG_FILE, image_name, write_pose
from lightstage_physics.errors import DestinationError
from lightstage_physics.output_files import writable_dir
from lightstage_physics.rig import CHANNELS, N_CHANNELS, N_SITES, Rig

from .capture_settings import CaptureSettings

__all__ = ["Destination", "check_destination", "write_model", "capture_rig", "validate_name",
           "rig_differences", "folder_rig", "model_files", "STAGING_DIR"]

STAGING_DIR = ".staging"
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


def validate_name(kind: str, value: str) -> str:
    """A label / sample / pose folder name: letters, digits, ``_ . + -``, not starting with
    a dot (hidden folders are ignored by the loader) or a separator."""
    text = str(value).strip()
    if not NAME.match(text):
        raise DestinationError(
            f"{kind} {value!r} is not a usable folder name: use letters, digits and _ . + - "
            f"(not starting with . or -), e.g. "
            + {"label": "'banana-fake'", "sample": "'s0'", "pose": "'p00'"}.get(kind, "'x0'"))
    return text


def capture_rig(settings: CaptureSettings, image_shape: tuple[int, int],
                base: Rig | None = None) -> Rig:
    """The rig.yaml of this capture: `base`'s sites (default: the paper's stage) with the
    capture's camera setting, image size and frame count."""
    base = base if base is not None else Rig.paper_default(tuple(image_shape))
    if base.n_sites != settings.n_sites:
        raise DestinationError(f"the rig description has {base.n_sites} sites but the stage "
                               f"capture lights {settings.n_sites}; fix rig_file")
    return replace(base, bit_depth=int(settings.bit_depth), image_size=tuple(image_shape),
                   exposure_us=float(settings.exposure_us), gain_db=float(settings.gain_db),
                   frames_averaged=int(settings.frames))


def rig_differences(existing: Rig, new: Rig, compare_sites: bool = True) -> list[str]:
    """What differs between a folder's rig.yaml and this capture's (empty: consistent)."""
    diffs = []
    for name, a, b in (("camera.bit_depth", existing.bit_depth, new.bit_depth),
                       ("camera.image_height x image_width", tuple(existing.image_size),
                        tuple(new.image_size)),
                       ("camera.exposure_us", existing.exposure_us, new.exposure_us),
                       ("camera.gain_db", existing.gain_db, new.gain_db),
                       ("camera.frames_averaged", existing.frames_averaged, new.frames_averaged),
                       ("number of sites", existing.n_sites, new.n_sites)):
        if isinstance(a, float) or isinstance(b, float):
            same = math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-6)
        else:
            same = a == b
        if not same:
            diffs.append(f"{name}: folder {a}, this capture {b}")
    if compare_sites and existing.n_sites == new.n_sites:
        for i, (a, b) in enumerate(zip(existing.sites, new.sites)):
            if not np.allclose(a.position_mm, b.position_mm, atol=1e-3):
                diffs.append(f"site {i} position: folder {a.position_mm} mm, rig_file "
                             f"{b.position_mm} mm")
    return diffs


@dataclass(frozen=True)
class Destination:
    """Where a pose goes, checked: `rig` is what the folder's rig.yaml says (or will say)."""
    root: Path
    label: str
    sample: str
    pose: str
    rig: Rig
    rig_exists: bool
    pose_exists: bool

    @property
    def pose_dir(self) -> Path:
        return self.root / self.label / self.sample / self.pose

    @property
    def name(self) -> str:
        return f"{self.label}/{self.sample}/{self.pose}"


def folder_rig(root) -> Rig | None:
    """The rig.yaml of an existing capture folder, None if there is none yet."""
    rig_path = Path(root) / RIG_FILE
    if not rig_path.is_file():
        return None
    try:
        return Rig.load_yaml(rig_path)
    except Exception as exc:  # noqa: BLE001 - yaml errors, missing keys, bad values
        raise DestinationError(f"{rig_path} does not load ({exc}); fix it or write into a "
                               "new folder") from None


def check_destination(root, label: str, sample: str, pose: str, rig: Rig, *,
                      overwrite: bool = False, rig_from_file: bool = False) -> Destination:
    """Check a pose can be written: names, writable folder, rig.yaml agreement, no overwrite.

    `rig` is this capture's rig (`capture_rig`). If the folder has a rig.yaml, its camera
    setting, image size, frame count and number of sites must equal this capture's (and the
    site positions too when `rig_from_file`, i.e. the node was given an explicit rig file);
    the folder's own rig (with its site geometry) is what stays. Raises DestinationError.
    """
    root = Path(root).expanduser()
    if not str(root).strip() or str(root) == ".":
        raise DestinationError("no output folder given; give the capture folder to write into "
                               "(created if missing)")
    label, sample, pose = (validate_name("label", label), validate_name("sample", sample),
                           validate_name("pose", pose))
    if root.exists() and not root.is_dir():
        raise DestinationError(f"{root} exists and is not a folder; give a capture folder")
    writable_dir(root)
    rig_path = root / RIG_FILE
    existing = folder_rig(root)
    rig_exists = existing is not None
    final_rig = rig
    if rig_exists:
        diffs = rig_differences(existing, rig, compare_sites=rig_from_file)
        if diffs:
            raise DestinationError(
                f"{rig_path} disagrees with this capture: {'; '.join(diffs)}. Every pose of a "
                f"folder must be captured at the same setting: capture with the folder's "
                f"values (exposure_us {existing.exposure_us:g}, gain_db {existing.gain_db:g}, "
                f"frames {existing.frames_averaged}) or write into a new folder")
        final_rig = existing
    elif root.is_dir() and any(p for p in root.iterdir() if not p.name.startswith(".")):
        raise DestinationError(f"{root} is not empty but has no {RIG_FILE}: it is not a capture "
                               "folder; give a new or empty folder, or an existing capture "
                               "folder")
    pose_dir = root / label / sample / pose
    pose_exists = pose_dir.exists()
    if pose_exists and not overwrite:
        raise DestinationError(f"{pose_dir} already exists; choose another pose name, or ask to "
                               "overwrite it (overwrite: true / --overwrite)")
    if pose_exists and not pose_dir.is_dir():
        raise DestinationError(f"{pose_dir} exists and is not a folder; remove it")
    if pose_exists:
        strangers = _not_pose_files(pose_dir, final_rig.n_sites)
        if strangers:
            raise DestinationError(
                f"{pose_dir} exists and is not a pose folder (it holds {', '.join(strangers)}); "
                "overwrite replaces only a pose (its single-LED images), nothing else: choose "
                "another pose name, or move that folder away first")
    return Destination(root, label, sample, pose, final_rig, rig_exists, pose_exists)


def _not_pose_files(pose_dir: Path, n_sites: int, shown: int = 3) -> list[str]:
    """Up to `shown` entries of `pose_dir` that a pose folder does not hold (anything but
    its single-LED images), the count of the rest last; empty for a pose folder."""
    images = set(model_files(n_sites))
    strangers = sorted(p.name + ("/" if p.is_dir() else "") for p in pose_dir.iterdir()
                       if p.name not in images or not p.is_file())
    if len(strangers) > shown:
        return strangers[:shown] + [f"{len(strangers) - shown} more"]
    return strangers


def write_model(destination: Destination, model: np.ndarray, *, overwrite: bool = False,
                compress_level: int = 6) -> Path:
    """Write one pose atomically; returns the pose folder.

    The images go to a staging folder ``<root>/.staging/...`` (ignored by the loader), which
    is renamed to ``<label>/<sample>/<pose>`` only when all of them are written; a replaced
    pose is moved aside first and deleted after. The destination is checked again first (the
    folder may have changed during the capture). A new folder gets its rig.yaml.
    """
    d = check_destination(destination.root, destination.label, destination.sample,
                          destination.pose, destination.rig, overwrite=overwrite)
    rig = d.rig
    model = np.asarray(model, dtype=np.float32)
    expected = (N_CHANNELS, rig.n_sites, *rig.image_size)
    if model.shape != expected:
        raise DestinationError(f"model has shape {model.shape}, the folder's rig needs {expected}")
    created_root = not d.root.exists()
    staging_root = d.root / STAGING_DIR
    made: list[Path] = []
    try:
        d.root.mkdir(parents=True, exist_ok=True)
        staging_root.mkdir(exist_ok=True)
        # mkdir, not tempfile.mkdtemp: the folder becomes the pose folder, and mkdtemp's 0700
        # would keep it from everyone but the node's user (a pose folder gets the umask's mode)
        stage = staging_root / f"{d.label}.{d.sample}.{d.pose}.{os.getpid()}.{uuid.uuid4().hex[:12]}"
        stage.mkdir()
        write_pose(stage, model, rig.bit_depth, compress_level)
        if not d.rig_exists:
            tmp = staging_root / f"{RIG_FILE}.{os.getpid()}.tmp"
            rig.save_yaml(tmp)
            os.replace(tmp, d.root / RIG_FILE)
        for parent in (d.root / d.label, d.root / d.label / d.sample):
            if not parent.exists():
                parent.mkdir()
                made.append(parent)
        old = None
        if d.pose_dir.exists():
            old = staging_root / f"replaced.{d.label}.{d.sample}.{d.pose}.{os.getpid()}"
            os.rename(d.pose_dir, old)
        try:
            os.rename(stage, d.pose_dir)
        except OSError:
            if old is not None:
                os.rename(old, d.pose_dir)  # put the old pose back
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        for parent in reversed(made):
            try:
                parent.rmdir()
            except OSError:
                pass
        if created_root:
            shutil.rmtree(d.root, ignore_errors=True)
        raise DestinationError(f"could not write {d.pose_dir}: {exc}; nothing of this pose was "
                               "left in the folder") from None
    finally:
        for leftover in staging_root.glob(f"{d.label}.{d.sample}.{d.pose}.*") \
                if staging_root.exists() else []:
            shutil.rmtree(leftover, ignore_errors=True)
        try:
            staging_root.rmdir()  # only if empty
        except OSError:
            pass
    return d.pose_dir


def model_files(n_sites: int = N_SITES) -> list[str]:
    """The image file names of one pose, in LED (site-major) order."""
    return [image_name(s, c) for s in range(n_sites) for c in CHANNELS]
