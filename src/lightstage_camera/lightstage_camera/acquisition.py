"""Model acquisition: one averaged image per single LED, written into a capture folder.

The paper's model capture (Sect. "Scene Model Acquisition"): light each of the 32 LEDs
alone, expose long, average several frames, and keep the result as the sample's relightable
model. This module is that procedure without ROS (the acquisition node maps an action onto
it; tests drive it with a `sim_camera.SimCamera` directly):

1. `CaptureSettings` + `led_patterns`: what to light (one LED at full power per image,
   site-major ``led = site * 4 + channel``), for how long, at which gain, how many frames;
2. `check_exposure` (the preview): one frame per LED before the long capture; an LED image
   with more clipped pixels than allowed stops the capture *before* it starts, naming the LED
   and suggesting an exposure;
3. `capture_model`: frames of each LED in chunks (one stage request each), averaged in
   float64 (`FrameAverager`), pixels that reached the camera's maximum in any frame counted;
   `cancelled()` is checked between chunks and nothing is written on cancel;
4. `check_destination` / `write_model`: the pose goes into the folder atomically (a staging
   folder under ``<root>/.staging/`` renamed into place), refusing to overwrite an existing
   pose unless asked, and refusing a folder whose ``rig.yaml`` disagrees with this capture;
5. `acquire_pose`: 1-4 in order, the destination checked before anything is lit and again
   before writing. A capture that cannot be written (disk full, the pose appeared meanwhile)
   is not lost: it goes to a rescue file (`save_rescued`) that `write_rescued` (``lightstage
   capture DIR --from-rescued FILE``) writes into a folder later.

A frame source is a callable ``grab(led_patterns (32, k)) -> list of k uint16 frames``
(MSB-aligned ``mono16``, one per pattern, in pattern order). The acquisition node builds it
from the driver's ApplyPatterns and `frames.ImageMatcher`.
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .capture_format import RIG_FILE, image_name, write_pose
from .frames import AcquisitionError, mono16_to_gray
from .rig import CHANNELS, N_CHANNELS, Rig

__all__ = ["CaptureSettings", "CaptureCancelled", "DestinationError", "ExposureError",
           "FrameAverager", "CapturedModel", "ExposureCheck", "led_name", "led_patterns",
           "check_exposure", "capture_model", "check_destination", "write_model",
           "capture_rig", "validate_name", "rig_differences", "Destination", "model_files",
           "folder_rig", "check_output_file", "acquire_pose", "save_rescued", "load_rescued",
           "save_in_rescue_dir",
           "write_rescued", "rescue_dirs", "RescuedModel",
           "STAGING_DIR", "MAX_FRAMES_PER_REQUEST"]

Grab = Callable[[np.ndarray], Sequence[np.ndarray]]
STAGING_DIR = ".staging"
# one stage request's frames must fit the camera's image queue (reliable, keep-last 32)
MAX_FRAMES_PER_REQUEST = 32
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


class CaptureCancelled(AcquisitionError):
    """The capture was cancelled between images; nothing was written."""


class DestinationError(AcquisitionError):
    """The capture folder / pose cannot take this capture; the message says what to do."""


class ExposureError(AcquisitionError):
    """The preview found clipped LED images; the message names them and suggests an exposure."""


# --------------------------------------------------------------------------- plan


def led_name(led: int, n_sites: int = 8) -> str:
    """``s<site>_<channel>`` of a site-major LED index (the image's file name stem)."""
    if not 0 <= int(led) < n_sites * N_CHANNELS:
        raise ValueError(f"LED {led} out of range 0..{n_sites * N_CHANNELS - 1}")
    return f"s{int(led) // N_CHANNELS}_{CHANNELS[int(led) % N_CHANNELS]}"


def led_patterns(n_sites: int = 8) -> np.ndarray:
    """``(n_leds, n_leds)`` float32: column ``led`` lights that LED alone at full power."""
    return np.eye(n_sites * N_CHANNELS, dtype=np.float32)


@dataclass(frozen=True)
class CaptureSettings:
    """One model capture: camera setting, frames averaged per LED image, request size.

    exposure_us           exposure (and LED on-time) per frame [us]
    gain_db               camera gain [dB] (recorded in rig.yaml with the exposure)
    frames                frames averaged per single-LED image
    bit_depth             significant bits of the camera's mono16 images
    n_sites               illumination sites (4 LEDs each)
    frames_per_request    frames per stage request (one trigger sequence)
    max_saturated_fraction  preview: largest fraction of an LED image's pixels allowed at the
                          camera's maximum before the capture is refused
    """
    exposure_us: int = 30000
    gain_db: float = 15.0
    frames: int = 16
    bit_depth: int = 10
    n_sites: int = 8
    frames_per_request: int = 16
    max_saturated_fraction: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.exposure_us, bool) or int(self.exposure_us) != self.exposure_us \
                or self.exposure_us < 1:
            raise ValueError(f"exposure_us must be a whole number of microseconds >= 1, got "
                             f"{self.exposure_us}")
        if not math.isfinite(self.gain_db):
            raise ValueError(f"gain_db must be a finite number of dB, got {self.gain_db}")
        if int(self.frames) != self.frames or self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if not 8 <= int(self.bit_depth) <= 16:
            raise ValueError(f"bit_depth must be 8..16, got {self.bit_depth}")
        if int(self.n_sites) < 1:
            raise ValueError(f"n_sites must be >= 1, got {self.n_sites}")
        if not 1 <= int(self.frames_per_request) <= MAX_FRAMES_PER_REQUEST:
            raise ValueError(f"frames_per_request must be 1..{MAX_FRAMES_PER_REQUEST}, got "
                             f"{self.frames_per_request}")
        if not 0.0 <= self.max_saturated_fraction <= 1.0:
            raise ValueError(f"max_saturated_fraction must be in [0, 1], got "
                             f"{self.max_saturated_fraction}")

    @property
    def n_leds(self) -> int:
        return int(self.n_sites) * N_CHANNELS

    @property
    def max_level(self) -> int:
        return (1 << int(self.bit_depth)) - 1

    @property
    def total_frames(self) -> int:
        return self.n_leds * int(self.frames)


# --------------------------------------------------------------------------- averaging


class FrameAverager:
    """Running mean of frames in float64, and which pixels ever reached the camera's maximum.

    A pixel that hit the maximum in any frame was clipped there: its average is biased low
    (the camera cannot report more), so it is counted as saturated.
    """

    def __init__(self, max_level: int):
        self.max_level = float(max_level)
        self.count = 0
        self._sum: np.ndarray | None = None
        self._saturated: np.ndarray | None = None

    def add(self, gray: np.ndarray) -> None:
        gray = np.asarray(gray)
        if gray.ndim != 2:
            raise ValueError(f"a frame must be an (H, W) image, got shape {gray.shape}")
        if self._sum is None:
            self._sum = np.zeros(gray.shape, np.float64)
            self._saturated = np.zeros(gray.shape, bool)
        elif gray.shape != self._sum.shape:
            raise ValueError(f"frame of {gray.shape[1]}x{gray.shape[0]} px after frames of "
                             f"{self._sum.shape[1]}x{self._sum.shape[0]} px; the camera changed "
                             "its image size during the capture")
        self._sum += gray
        self._saturated |= gray >= self.max_level
        self.count += 1

    @property
    def shape(self) -> tuple[int, int] | None:
        return None if self._sum is None else tuple(self._sum.shape)

    def mean(self) -> np.ndarray:
        if self.count == 0:
            raise ValueError("no frames averaged yet")
        return (self._sum / self.count).astype(np.float32)

    @property
    def saturated(self) -> np.ndarray:
        if self._saturated is None:
            raise ValueError("no frames averaged yet")
        return self._saturated

    @property
    def saturated_pixels(self) -> int:
        return 0 if self._saturated is None else int(self._saturated.sum())


# --------------------------------------------------------------------------- the preview


@dataclass
class ExposureCheck:
    """One frame per LED at the capture setting: how close each LED image comes to clipping.

    peak_level   per LED, the 99.9th percentile gray level of its frame
    clipped      per LED, the fraction of pixels at the camera's maximum
    image_shape  (H, W) of the camera's frames
    """
    settings: CaptureSettings
    peak_level: np.ndarray
    clipped: np.ndarray
    image_shape: tuple[int, int]

    @property
    def brightest_led(self) -> int:
        return int(np.argmax(self.peak_level + self.clipped * 1e6))

    def suggested_exposure_us(self, target_fraction: float = 0.8) -> int:
        """An exposure that puts the brightest LED image's 99.9th percentile at
        `target_fraction` of the range, assuming the camera's response is linear in exposure.
        When that LED is clipped its true level is unknown: half the exposure, at most."""
        s = self.settings
        peak = float(np.max(self.peak_level))
        factor = target_fraction * s.max_level / max(peak, 1.0)
        if np.any(self.clipped > 0):
            factor = min(factor, 0.5)
        return max(1, int(s.exposure_us * factor))

    def problems(self) -> list[str]:
        """Human-readable problems: LED images with more clipped pixels than allowed."""
        s = self.settings
        bad = np.flatnonzero(self.clipped > s.max_saturated_fraction)
        return [f"{led_name(i, s.n_sites)} has {100 * self.clipped[i]:.2g} % of its pixels at the "
                f"camera's maximum ({s.max_level})" for i in bad]


def check_exposure(grab: Grab, settings: CaptureSettings,
                   cancelled: Callable[[], bool] | None = None) -> ExposureCheck:
    """The preview: one frame per LED; raises ExposureError if an LED image clips too much."""
    patterns = led_patterns(settings.n_sites)
    peaks, clipped, shape = [], [], None
    for start in range(0, settings.n_leds, settings.frames_per_request):
        if cancelled is not None and cancelled():
            raise CaptureCancelled("cancelled during the exposure preview; nothing was written")
        chunk = patterns[:, start:start + settings.frames_per_request]
        frames = _grab(grab, chunk)
        for frame in frames:
            gray = mono16_to_gray(frame, settings.bit_depth)
            if shape is None:
                shape = gray.shape
            peaks.append(float(np.percentile(gray, 99.9)))
            clipped.append(float(np.mean(gray >= settings.max_level)))
    check = ExposureCheck(settings, np.array(peaks), np.array(clipped), tuple(shape))
    problems = check.problems()
    if problems:
        raise ExposureError(
            f"the exposure preview at exposure_us {settings.exposure_us}, gain_db "
            f"{settings.gain_db:g} clips: {'; '.join(problems)}. Lower the exposure (about "
            f"exposure_us {check.suggested_exposure_us()} puts the brightest LED image at 80 % "
            f"of the range) or the gain, or allow some clipped pixels with the node's "
            f"max_saturated_fraction parameter. Nothing was captured.")
    return check


# --------------------------------------------------------------------------- the capture


@dataclass
class CapturedModel:
    """The averaged single-LED images of one pose, ready to write.

    model            (4, n_sites, H, W) float32 gray levels, channel-major (capture format)
    saturated        (n_leds,) pixels of each LED image that reached the maximum in a frame
    frames           frames averaged per image
    """
    model: np.ndarray
    saturated: np.ndarray
    frames: int
    settings: CaptureSettings
    elapsed_s: float = 0.0
    preview: ExposureCheck | None = field(default=None, repr=False)

    @property
    def saturated_pixels(self) -> int:
        return int(np.sum(self.saturated))

    def saturation_warning(self) -> str:
        """'' when no pixel clipped, else which LED images and what to do."""
        if self.saturated_pixels == 0:
            return ""
        n = self.settings.n_sites
        worst = [f"{led_name(i, n)} ({int(self.saturated[i])} px)"
                 for i in np.argsort(-self.saturated)[:4] if self.saturated[i] > 0]
        return (f"{self.saturated_pixels} pixels reached the camera's maximum in at least one "
                f"frame ({', '.join(worst)}): their averages are biased low. Recapture with "
                "a lower exposure_us or gain_db if those pixels matter")


def _grab(grab: Grab, patterns: np.ndarray) -> list[np.ndarray]:
    frames = list(grab(patterns))
    if len(frames) != patterns.shape[1]:
        raise AcquisitionError(f"asked the stage for {patterns.shape[1]} frames, got "
                               f"{len(frames)}")
    return frames


def capture_model(grab: Grab, settings: CaptureSettings, *,
                  on_image: Callable[[int, int, str], None] | None = None,
                  cancelled: Callable[[], bool] | None = None,
                  preview: bool = True) -> CapturedModel:
    """Capture one pose: per LED, `settings.frames` frames averaged.

    `on_image(images_done, images_total, led_name)` after each LED image; `cancelled()` is
    asked before every stage request and raises CaptureCancelled (nothing written: this
    function never writes). `preview` runs `check_exposure` first.
    """
    start = time.perf_counter()
    check = check_exposure(grab, settings, cancelled) if preview else None
    patterns = led_patterns(settings.n_sites)
    images: list[np.ndarray] = []
    saturated = np.zeros(settings.n_leds, np.int64)
    for led in range(settings.n_leds):
        averager = FrameAverager(settings.max_level)
        remaining = int(settings.frames)
        while remaining > 0:
            if cancelled is not None and cancelled():
                raise CaptureCancelled(f"cancelled at {led_name(led, settings.n_sites)} "
                                       f"({led} of {settings.n_leds} LED images done); nothing "
                                       "was written")
            k = min(remaining, int(settings.frames_per_request))
            chunk = np.repeat(patterns[:, led:led + 1], k, axis=1)
            for frame in _grab(grab, chunk):
                averager.add(mono16_to_gray(frame, settings.bit_depth))
            remaining -= k
        if images and averager.shape != images[0].shape:
            raise AcquisitionError(f"{led_name(led, settings.n_sites)}: the camera's images "
                                   f"changed size during the capture")
        images.append(averager.mean())
        saturated[led] = averager.saturated_pixels
        if on_image is not None:
            on_image(led + 1, settings.n_leds, led_name(led, settings.n_sites))
    stack = np.stack(images)  # (n_leds, H, W), site-major
    h, w = stack.shape[1:]
    model = stack.reshape(settings.n_sites, N_CHANNELS, h, w).transpose(1, 0, 2, 3)
    return CapturedModel(np.ascontiguousarray(model), saturated, int(settings.frames), settings,
                         time.perf_counter() - start, check)


# --------------------------------------------------------------------------- the folder


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


def _writable_dir(path: Path) -> None:
    """Raise DestinationError unless `path` (existing, or its first existing parent) can take
    new files; checked by creating and removing a file, not by permission bits alone."""
    probe_dir = path
    while not probe_dir.exists():
        if probe_dir.parent == probe_dir:
            break
        probe_dir = probe_dir.parent
    if not probe_dir.is_dir():
        raise DestinationError(f"{probe_dir} is not a folder; give a path in a folder")
    try:
        fd, name = tempfile.mkstemp(prefix=".lightstage-write-test-", dir=probe_dir)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise DestinationError(f"cannot write into {probe_dir} ({exc.strerror or exc}); give a "
                               "writable folder") from None


def folder_rig(root) -> Rig | None:
    """The rig.yaml of an existing capture folder, None if there is none yet."""
    rig_path = Path(root) / RIG_FILE
    if not rig_path.is_file():
        return None
    try:
        return Rig.load_yaml(rig_path)
    except Exception as exc:  # yaml errors, missing keys, bad values
        raise DestinationError(f"{rig_path} does not load ({exc}); fix it or write into a "
                               "new folder") from None


def check_output_file(path, overwrite: bool = False) -> Path:
    """A file about to be written (a noise file, a plot): refuses to replace one unless
    `overwrite`, and checks its folder (or the first existing parent) takes new files."""
    path = Path(path).expanduser()
    if path.is_dir():
        raise DestinationError(f"{path} is a folder; give a file name")
    if path.exists() and not overwrite:
        raise DestinationError(f"{path} already exists; choose another name or ask to "
                               "overwrite it (overwrite: true / --overwrite)")
    _writable_dir(path.parent)
    return path


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
    _writable_dir(root)
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
    return Destination(root, label, sample, pose, final_rig, rig_exists, pose_exists)


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
        stage = Path(tempfile.mkdtemp(prefix=f"{d.label}.{d.sample}.{d.pose}.", dir=staging_root))
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


def model_files(n_sites: int = 8) -> list[str]:
    """The image file names of one pose, in LED (site-major) order."""
    return [image_name(s, c) for s in range(n_sites) for c in CHANNELS]



# --------------------------------------------------------------------------- one pose, end to end


def acquire_pose(grab: Grab, settings: CaptureSettings, root, label: str, sample: str, pose: str,
                 *, base_rig: Rig | None = None, overwrite: bool = False, preview: bool = True,
                 cancelled: Callable[[], bool] | None = None,
                 before_capture: Callable[[], None] | None = None,
                 on_progress: Callable[[int, int, str, str], None] | None = None,
                 ) -> tuple[Path, CapturedModel]:
    """Capture one pose into the capture folder ``root``; returns (pose folder, capture).

    The destination (names, writable folder, rig.yaml agreement, existing pose) is checked
    before anything is lit, with the preview's image size again after the preview, and with
    the captured size before writing. ``base_rig`` is an explicit rig description (site
    geometry; None: the folder's, else the paper's stage). ``before_capture()`` runs once
    the destination is checked (the node waits for its stage there).
    ``on_progress(images_done, images_total, led_name, stage)`` with stage 'preview',
    'capturing', 'writing'. A capture that cannot be written raises DestinationError naming
    the rescue file it was saved to instead.
    """
    root = Path(root).expanduser() if str(root).strip() else Path("")
    existing = folder_rig(root) if str(root) != "." else None  # "" / "." refused below

    def destination(shape) -> Destination:
        return check_destination(root, label, sample, pose,
                                 capture_rig(settings, tuple(shape), base_rig or existing),
                                 overwrite=overwrite, rig_from_file=base_rig is not None)

    destination(existing.image_size if existing else (1, 1))
    if before_capture is not None:
        before_capture()
    report = on_progress or (lambda *_a: None)
    total = settings.n_leds
    check = None
    if preview:
        report(0, total, "", "preview")
        check = check_exposure(grab, settings, cancelled)
        destination(check.image_shape)
    captured = capture_model(grab, settings, preview=False, cancelled=cancelled,
                             on_image=lambda done, n, led: report(done, n, led, "capturing"))
    captured.preview = check
    report(total, total, "", "writing")
    try:
        target = destination(captured.model.shape[-2:])
        return write_model(target, captured.model, overwrite=overwrite), captured
    except DestinationError as exc:
        rig = capture_rig(settings, captured.model.shape[-2:], base_rig or existing)
        raise DestinationError(_rescue(exc, RescuedModel(root, label, sample, pose, rig,
                                                         captured.model))) from None


# --------------------------------------------------------------------------- rescue files
RESCUE_DIR_ENV = "LIGHTSTAGE_RESCUE_DIR"
RESCUE_KIND = "lightstage-rescued-model"
RESCUE_VERSION = 1


@dataclass
class RescuedModel:
    """A captured pose that could not be written where it was meant to go."""
    root: Path
    label: str
    sample: str
    pose: str
    rig: Rig
    model: np.ndarray


def rescue_dirs() -> list[Path]:
    """Where rescue files go, in order of preference: $LIGHTSTAGE_RESCUE_DIR, the user's
    cache folder, the temporary folder (another file system than a full capture disk, often)."""
    dirs = [Path(os.environ[RESCUE_DIR_ENV]).expanduser()] if os.environ.get(RESCUE_DIR_ENV) else []
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return dirs + [Path(cache) / "lightstage" / "rescued",
                   Path(tempfile.gettempdir()) / "lightstage-rescued"]


def save_in_rescue_dir(file_name: str, write: Callable[[Path], None]) -> Path:
    """`write(path)` a file named `file_name` into the first rescue folder that takes it;
    returns its path. Raises OSError naming each folder's error when none does."""
    errors = []
    for folder in rescue_dirs():
        path = folder / file_name
        try:
            folder.mkdir(parents=True, exist_ok=True)
            write(path)
            return path
        except OSError as exc:
            errors.append(f"{folder}: {exc.strerror or exc}")
            try:
                path.unlink()
            except OSError:
                pass
    raise OSError("; ".join(errors))


def save_rescued(rescued: RescuedModel) -> Path:
    """Save a pose to the first rescue folder that takes it (an ``.npz`` that loads without
    pickle: the model and a JSON header). Raises OSError when none does."""
    header = json.dumps({"kind": RESCUE_KIND, "version": RESCUE_VERSION,
                         "root": str(Path(rescued.root).absolute()), "label": rescued.label,
                         "sample": rescued.sample, "pose": rescued.pose,
                         "rig": rescued.rig.to_dict()})
    stamp = time.strftime("%Y%m%d-%H%M%S")

    def write(path: Path) -> None:
        with open(path, "wb") as f:
            np.savez(f, model=np.asarray(rescued.model, np.float32), header=np.array(header))

    return save_in_rescue_dir(
        f"{rescued.label}.{rescued.sample}.{rescued.pose}.{stamp}.{os.getpid()}.npz", write)


def load_rescued(path) -> RescuedModel:
    """A rescue file written by `save_rescued`; DestinationError if it is not one."""
    path = Path(path).expanduser()
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            model = np.asarray(data["model"], np.float32)
        if header.get("kind") != RESCUE_KIND or header.get("version") != RESCUE_VERSION:
            raise ValueError(f"not a rescue file of version {RESCUE_VERSION}")
        rig = Rig.from_dict(header["rig"], source=str(path))
        return RescuedModel(Path(header["root"]), header["label"], header["sample"],
                            header["pose"], rig, model)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DestinationError(f"{path} is not a readable rescue file ({exc}); give the file "
                               "named in the capture's error message") from None


def write_rescued(path, root=None, *, overwrite: bool = False) -> Path:
    """Write a rescue file's pose into ``root`` (default: the folder it was meant for) as a
    capture would have, then delete the rescue file; returns the pose folder."""
    rescued = load_rescued(path)
    root = Path(root).expanduser() if root else rescued.root
    target = check_destination(root, rescued.label, rescued.sample, rescued.pose, rescued.rig,
                               overwrite=overwrite, rig_from_file=True)
    pose_dir = write_model(target, rescued.model, overwrite=overwrite)
    Path(path).expanduser().unlink()
    return pose_dir


def _rescue(error: Exception, rescued: RescuedModel) -> str:
    """The message of a capture that could not be written, with where it was kept."""
    try:
        kept = save_rescued(rescued)
    except OSError as exc:
        return (f"{error}. The captured images could not be kept anywhere else either ({exc}): "
                "free space and capture the pose again")
    return (f"{error}. The captured images are kept in {kept}: fix that, then write them with "
            f"`lightstage capture {rescued.root} --from-rescued {kept}` instead of capturing "
            "again")
