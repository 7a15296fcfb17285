"""Noise calibration: fit the affine noise model from frames of a target under several lights.

As in the paper: image a target of smoothly varying reflectance at increasing illumination,
many frames per level; every pixel gives one (mean, variance) point; a robust line through
the points gives variance = sigma_p2 * mean + sigma_r2 at the camera's current setting.
`NoiseModel.at` then generalizes it to other gains and exposures.

Acquisition on the stage (`calibrate_noise`, no rclpy; the acquisition node's CalibrateNoise
action maps onto it): the target lies on the stage, `calibration_patterns` light more and
more LEDs (nested sets, the LEDs interleaved over sites and colours so the light stays
spread), many frames per level at one gain / exposure; per-pixel moments are accumulated
frame by frame (`PixelMoments`), so no frame stack is held in memory. `fit_uncertainty`
gives the fit's standard errors from the number of frames and pixels; `write_calibration_target`
writes a target as a capture folder the simulated camera can put on the stage.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .noise import NoiseModel


@dataclass
class NoiseCharacteristic:
    """Per-pixel statistics of a calibration capture, binned along the mean."""
    pixel_mean: np.ndarray  # every usable pixel's mean over frames
    pixel_var: np.ndarray  # and its unbiased variance
    bin_mean: np.ndarray  # mean of pixel_mean in each bin
    bin_var: np.ndarray  # mean of pixel_var in each bin (unbiased, unlike a median)
    n_frames: int
    bin_count: np.ndarray | None = None  # pixels in each bin


def _as_stacks(levels_frames) -> list[np.ndarray]:
    stacks = [np.asarray(f, dtype=np.float64) for f in levels_frames]
    if not stacks:
        raise ValueError("no calibration levels given; pass one (n_frames, H, W) stack per level")
    for i, s in enumerate(stacks):
        if s.ndim < 2 or s.shape[0] < 2:
            raise ValueError(f"level {i}: need a stack of at least 2 frames (n_frames, H, W), "
                             f"got shape {s.shape}")
    return stacks


def noise_characteristic(levels_frames, max_level: int = 1023, n_bins: int = 60,
                         clip_sigmas: float = 4.0) -> NoiseCharacteristic:
    """Per-pixel mean and variance over frames, keeping pixels clear of 0 and saturation.

    A pixel whose mean lies within `clip_sigmas` standard deviations of 0 or `max_level`
    has a clipped distribution (variance shrinks, as in the paper's figure) and is dropped.
    """
    moments = []
    for stack in _as_stacks(levels_frames):
        moments.append((stack.mean(axis=0), stack.var(axis=0, ddof=1), stack.shape[0]))
    return characteristic_from_moments(moments, max_level, n_bins, clip_sigmas)


def characteristic_from_moments(moments, max_level: int = 1023, n_bins: int = 60,
                                clip_sigmas: float = 4.0) -> NoiseCharacteristic:
    """`noise_characteristic` from per-level ``(pixel mean, unbiased variance, n_frames)``."""
    means, variances, n_frames = [], [], []
    for m, v, n in moments:
        m, v = np.asarray(m, np.float64).ravel(), np.asarray(v, np.float64).ravel()
        sd = np.sqrt(v)
        keep = (m - clip_sigmas * sd > 0) & (m + clip_sigmas * sd < max_level)
        means.append(m[keep])
        variances.append(v[keep])
        n_frames.append(int(n))
    if not means:
        raise ValueError("no calibration levels given; pass one (n_frames, H, W) stack per level")
    mean, var = np.concatenate(means), np.concatenate(variances)
    if mean.size < 10:
        raise ValueError("fewer than 10 usable pixels: every level is saturated or black; "
                         "use illumination levels that span the camera's range")
    edges = np.unique(np.quantile(mean, np.linspace(0, 1, n_bins + 1)))
    which = np.clip(np.searchsorted(edges, mean, side="right") - 1, 0, len(edges) - 2)
    counts = np.bincount(which, minlength=len(edges) - 1)
    ok = counts > 0
    bin_mean = np.bincount(which, mean, len(edges) - 1)[ok] / counts[ok]
    bin_var = np.bincount(which, var, len(edges) - 1)[ok] / counts[ok]
    return NoiseCharacteristic(mean, var, bin_mean, bin_var, int(min(n_frames)), counts[ok])


def fit_line_robust(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope and intercept of a Huber-loss line fit (robust to stray bins)."""
    from sklearn.linear_model import HuberRegressor

    scale = float(np.max(np.abs(x))) or 1.0  # conditioning: x in [0, 1]
    model = HuberRegressor(epsilon=1.35, alpha=0.0, max_iter=1000).fit(x[:, None] / scale, y)
    return float(model.coef_[0] / scale), float(model.intercept_)


def fit_noise_model(levels_frames, gain_db: float = 15.0, exposure_ms: float = 30.0,
                    max_level: int = 1023) -> NoiseModel:
    """The affine noise model at the capture's (gain, exposure) from calibration frames.

    `levels_frames`: one array (n_frames, H, W) per illumination level (an array
    (n_levels, n_frames, H, W) works too), gray levels in camera units; or a
    NoiseCharacteristic already computed from them.
    """
    if isinstance(levels_frames, NoiseCharacteristic):
        char = levels_frames
    else:
        char = noise_characteristic(levels_frames, max_level)
    if len(char.bin_mean) < 2 or np.ptp(char.bin_mean) < 1e-6:
        raise ValueError("all usable pixels have the same mean; the fit needs a range of "
                         "brightness (a graded target or several illumination levels)")
    slope, intercept = fit_line_robust(char.bin_mean, char.bin_var)
    if slope < 0 or intercept < 0:
        raise ValueError(f"fitted a negative noise term (sigma_p2={slope:.3g}, "
                         f"sigma_r2={intercept:.3g}); check the frames are of a static scene")
    return NoiseModel(slope, intercept, gain_db=gain_db, exposure_ms=exposure_ms,
                      max_level=max_level)


def fit_uncertainty(char: NoiseCharacteristic, fit: NoiseModel) -> tuple[float, float]:
    """Standard errors of (sigma_p2, sigma_r2) of a fit to `char`, from frames and pixels.

    A pixel's unbiased variance from n Gaussian frames has variance 2 sigma^4 / (n - 1); a
    bin's mean of c such pixels 2 sigma^4 / ((n - 1) c), sigma^2 the fitted variance at the
    bin's mean. The line through the bins is (nearly) ordinary least squares, so its
    covariance is the sandwich (X'X)^-1 X' D X (X'X)^-1 with D those bin variances. This
    ignores the small loss of the Huber loss against least squares on clean data;
    tests/acquisition checks it against the spread of repeated simulated calibrations.
    """
    if char.bin_count is None:
        raise ValueError("the characteristic has no bin counts; compute it with "
                         "noise_characteristic / characteristic_from_moments")
    n = max(int(char.n_frames), 2)
    x = np.asarray(char.bin_mean, np.float64)
    var_y = 2.0 * fit.variance(x) ** 2 / ((n - 1) * np.asarray(char.bin_count, np.float64))
    X = np.column_stack([x, np.ones_like(x)])
    xtx_inv = np.linalg.inv(X.T @ X)
    cov = xtx_inv @ (X.T * var_y) @ X @ xtx_inv
    return float(math.sqrt(cov[0, 0])), float(math.sqrt(cov[1, 1]))


def calibration_target(shape=(48, 64)) -> np.ndarray:
    """Reflectance in (0.05, 1): a smooth ramp across, gently modulated down (the test chart)."""
    h, w = shape
    ramp = np.linspace(0.05, 1.0, w)[None, :]
    wave = 1.0 - 0.1 * np.sin(np.linspace(0, np.pi, h))[:, None]
    return ramp * wave


def simulate_calibration_frames(noise_model: NoiseModel, n_levels: int = 8, n_frames: int = 120,
                                shape=(48, 64), peak_level: float | None = None,
                                rng: np.random.Generator | None = None,
                                quantize: bool = True) -> list[np.ndarray]:
    """Frames of the calibration target at `n_levels` increasing illuminations.

    Each level is a float32 stack (n_frames, H, W) drawn from `noise_model` (clipped, and
    rounded to whole gray levels like a real camera when `quantize`). The brightest level
    reaches `peak_level` (default: 1.05 x max_level, so its top end saturates).
    """
    rng = np.random.default_rng() if rng is None else rng
    peak = 1.05 * noise_model.max_level if peak_level is None else peak_level
    target = calibration_target(shape).astype(np.float32)
    stacks = []
    for level in np.linspace(1.0 / n_levels, 1.0, n_levels):
        mean = np.broadcast_to(target * np.float32(peak * level), (n_frames, *shape))
        frames = noise_model.sample(mean, rng)
        if quantize:
            np.rint(frames, out=frames)
        stacks.append(frames)
    return stacks


# --------------------------------------------------------------------------- on the stage


class PixelMoments:
    """Per-pixel mean and unbiased variance of frames, accumulated one frame at a time.

    Sums of differences from the first frame (float64), so that a pixel's variance does not
    drown in the rounding of its squared mean.
    """

    def __init__(self):
        self.count = 0
        self._shift = self._s1 = self._s2 = None

    def add(self, gray: np.ndarray) -> None:
        gray = np.asarray(gray, np.float64)
        if self._shift is None:
            self._shift = gray.copy()
            self._s1 = np.zeros_like(gray)
            self._s2 = np.zeros_like(gray)
        elif gray.shape != self._shift.shape:
            raise ValueError(f"frame of shape {gray.shape} after frames of {self._shift.shape}; "
                             "the camera changed its image size during the calibration")
        d = gray - self._shift
        self._s1 += d
        self._s2 += d * d
        self.count += 1

    def mean(self) -> np.ndarray:
        return self._shift + self._s1 / self.count

    def variance(self) -> np.ndarray:
        if self.count < 2:
            raise ValueError("a variance needs at least 2 frames")
        return (self._s2 - self._s1 * self._s1 / self.count) / (self.count - 1)


def calibration_led_order(n_sites: int = 8) -> list[int]:
    """LEDs in the order levels add them: every run of 4 has one LED of each colour, at
    sites spread around the stage (channel c, run r: site (r + 2c) mod n_sites)."""
    order = []
    for k in range(n_sites * 4):
        c, r = k % 4, k // 4
        order.append(((r + 2 * c) % n_sites) * 4 + c)
    return order


def calibration_patterns(n_levels: int, n_sites: int = 8) -> np.ndarray:
    """``(n_leds, n_levels)`` on/off patterns of increasing illumination: level i lights the
    first round(n_leds * i / n_levels) LEDs of `calibration_led_order` (nested sets; works on
    on/off and PWM stages alike). The last level lights every LED."""
    n_leds = n_sites * 4
    if not 2 <= int(n_levels) <= n_leds:
        raise ValueError(f"n_levels must be 2..{n_leds} (one more LED per level at most), "
                         f"got {n_levels}")
    order = calibration_led_order(n_sites)
    patterns = np.zeros((n_leds, int(n_levels)), np.float32)
    for i in range(int(n_levels)):
        lit = max(1, int(round(n_leds * (i + 1) / n_levels)))
        patterns[order[:lit], i] = 1.0
    return patterns


@dataclass(frozen=True)
class CalibrationSettings:
    """One noise calibration on the stage (the paper: 15 dB, 30 ms, 120 frames per level)."""
    exposure_us: int = 30000
    gain_db: float = 15.0
    frames_per_level: int = 120
    levels: int = 8
    bit_depth: int = 10
    n_sites: int = 8
    frames_per_request: int = 16

    def __post_init__(self) -> None:
        if int(self.exposure_us) != self.exposure_us or self.exposure_us < 1:
            raise ValueError(f"exposure_us must be a whole number of microseconds >= 1, got "
                             f"{self.exposure_us}")
        if not math.isfinite(self.gain_db):
            raise ValueError(f"gain_db must be a finite number of dB, got {self.gain_db}")
        if int(self.frames_per_level) < 2:
            raise ValueError(f"frames_per_level must be >= 2 (a variance needs two frames), "
                             f"got {self.frames_per_level}")
        if not 2 <= int(self.levels) <= 4 * int(self.n_sites):
            raise ValueError(f"levels must be 2..{4 * int(self.n_sites)}, got {self.levels}")
        if not 8 <= int(self.bit_depth) <= 16:
            raise ValueError(f"bit_depth must be 8..16, got {self.bit_depth}")
        if not 1 <= int(self.frames_per_request) <= 32:
            raise ValueError(f"frames_per_request must be 1..32, got {self.frames_per_request}")

    @property
    def max_level(self) -> int:
        return (1 << int(self.bit_depth)) - 1

    @property
    def exposure_ms(self) -> float:
        return float(self.exposure_us) / 1000.0


@dataclass
class CalibrationResult:
    """A fitted noise model with its standard errors and what it was fitted from."""
    model: NoiseModel
    stderr: tuple[float, float]  # (sigma_p2, sigma_r2)
    characteristic: NoiseCharacteristic = field(repr=False)
    settings: CalibrationSettings
    leds_lit: list[int]
    image_shape: tuple[int, int]
    elapsed_s: float = 0.0

    @property
    def pixels_used(self) -> int:
        return int(len(self.characteristic.pixel_mean))

    def warnings(self) -> list[str]:
        out = []
        top = float(np.max(self.characteristic.pixel_mean))
        max_level = self.settings.max_level
        if top < 0.5 * max_level:
            out.append(f"the usable pixel means reach only {top:.0f} gray levels "
                       f"({100 * top / max_level:.0f} % of the range), so the photon-noise "
                       "slope rests on a short stretch: light the target more (a brighter "
                       "target, a longer exposure) for a calibration over the whole range")
        return out

    def generalized(self) -> dict[str, NoiseModel]:
        """The fit generalized to the paper's Sigma1..3 settings (`NoiseModel.at`)."""
        from .noise import SETTINGS
        return {name: self.model.at(g, e) for name, (g, e) in SETTINGS.items()}


def calibrate_noise(grab: Callable[[np.ndarray], Sequence[np.ndarray]],
                    settings: CalibrationSettings, *,
                    on_frames: Callable[[int, int, int, int, int], None] | None = None,
                    cancelled: Callable[[], bool] | None = None,
                    on_fitting: Callable[[], None] | None = None,
                    n_bins: int = 60) -> CalibrationResult:
    """Calibrate on the stage: `settings.levels` illumination levels x frames, then the fit.

    `grab(led_patterns (n_leds, k)) -> k mono16 frames` (as for model capture).
    `on_frames(level, levels, frames_done, frames_total, leds_lit)` after each request;
    `cancelled()` before each request (raises acquisition.CaptureCancelled);
    `on_fitting()` once every frame is in, before the fit.
    """
    from .acquisition import CaptureCancelled
    from .frames import AcquisitionError, mono16_to_gray

    start = time.perf_counter()
    patterns = calibration_patterns(settings.levels, settings.n_sites)
    moments, leds_lit, shape = [], [], None
    for level in range(int(settings.levels)):
        acc = PixelMoments()
        lit = int(patterns[:, level].sum())
        leds_lit.append(lit)
        done = 0
        while done < settings.frames_per_level:
            if cancelled is not None and cancelled():
                raise CaptureCancelled(f"cancelled at level {level + 1} of {settings.levels}; "
                                       "nothing was written")
            k = min(int(settings.frames_per_request), int(settings.frames_per_level) - done)
            frames = list(grab(np.repeat(patterns[:, level:level + 1], k, axis=1)))
            if len(frames) != k:
                raise AcquisitionError(f"asked the stage for {k} frames, got {len(frames)}")
            for frame in frames:
                acc.add(mono16_to_gray(frame, settings.bit_depth))
            done += k
            if on_frames is not None:
                on_frames(level + 1, int(settings.levels), done, int(settings.frames_per_level), lit)
        shape = acc.mean().shape
        moments.append((acc.mean(), acc.variance(), acc.count))
    if on_fitting is not None:
        on_fitting()
    try:
        char = characteristic_from_moments(moments, settings.max_level, n_bins)
        fit = fit_noise_model(char, settings.gain_db, settings.exposure_ms, settings.max_level)
    except ValueError as exc:
        raise AcquisitionError(f"the noise fit failed: {exc}. Is the calibration target (a "
                               "flat chart of smoothly varying reflectance) on the stage and "
                               "lit by the LEDs?") from None
    return CalibrationResult(fit, fit_uncertainty(char, fit), char, settings, leds_lit,
                             tuple(shape), time.perf_counter() - start)


CALIBRATION_TARGET_NAME = "calibration-target/s0/p00"


def write_calibration_target(out_dir, shape=(48, 64), n_sites: int = 8,
                             peak_level: float | None = None, dimmer: float = 0.45,
                             bit_depth: int = 10, overwrite: bool = False) -> Path:
    """A capture folder holding one sample, ``calibration-target/s0/p00``: the flat chart of
    `calibration_target` (smooth reflectance ramp) under each single LED.

    Each LED lights it with its own strength (per colour and upper/lower site) and a gentle
    gradient from its side of the stage. All LEDs together, scaled by the simulated camera's
    `dimmer`, bring the brightest pixel to `peak_level` (default 1.1 x the camera's maximum:
    the brightest calibration level saturates its top end, as in the paper's curves).
    """
    from .capture_format import write_pose
    from .rig import Rig

    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"{out} is not empty; choose a new folder or pass overwrite")
    h, w = (int(shape), int(shape)) if np.isscalar(shape) else (int(shape[0]), int(shape[1]))
    if min(h, w) < 4:
        raise ValueError(f"the target needs at least 4 x 4 pixels, got {h} x {w}")
    if not dimmer > 0:
        raise ValueError(f"dimmer must be > 0, got {dimmer}")
    max_level = (1 << int(bit_depth)) - 1
    peak = 1.1 * max_level if peak_level is None else float(peak_level)
    rig = replace(Rig.paper_default((h, w)), bit_depth=int(bit_depth), frames_averaged=64)
    if rig.n_sites != n_sites:
        raise ValueError(f"the paper's stage has {rig.n_sites} sites, not {n_sites}")
    reflectance = calibration_target((h, w))
    yy, xx = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
    colour = np.array([1.0, 0.9, 0.8, 0.6])
    positions = rig.site_positions_mm()
    images = np.zeros((4, n_sites, h, w))
    for s in range(n_sites):
        az = math.atan2(positions[s, 1], positions[s, 0])
        gradient = 1.0 + 0.15 * (np.cos(az) * xx + np.sin(az) * yy)
        strength = 1.0 if s >= n_sites // 2 else 0.7
        for c in range(4):
            images[c, s] = reflectance * gradient * strength * colour[c]
    images *= peak / (dimmer * images.sum(axis=(0, 1)).max())
    if images.max() > max_level:
        raise ValueError(f"peak_level {peak:g} at dimmer {dimmer:g} needs single-LED images "
                         f"brighter than the camera's maximum; lower peak_level")
    out.mkdir(parents=True, exist_ok=True)
    rig.save_yaml(out / "rig.yaml")
    write_pose(out / CALIBRATION_TARGET_NAME, images.astype(np.float32), rig.bit_depth)
    return out


# what plot_noise_characteristic can draw into (matplotlib's Agg, PDF, SVG, PS backends)
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg", ".tif", ".tiff", ".eps", ".ps")
NOISE_FILE_SUFFIXES = (".yaml", ".yml")


def check_calibration_outputs(noise_path: str = "", plot_path: str = "",
                              overwrite: bool = False) -> tuple[Path | None, Path | None]:
    """The noise file and plot a calibration will write, checked before anything is lit:
    known suffixes (which also keeps the two apart), nothing replaced unless `overwrite`, folders that
    take new files. None for an empty path. Raises acquisition.DestinationError."""
    from .acquisition import DestinationError, check_output_file

    targets = []
    for path, suffixes, what in ((noise_path, NOISE_FILE_SUFFIXES, "noise file"),
                                 (plot_path, PLOT_SUFFIXES, "plot")):
        if not str(path).strip():
            targets.append(None)
            continue
        target = check_output_file(path, overwrite)
        if target.suffix.lower() not in suffixes:
            raise DestinationError(f"the {what} {target} should end in one of "
                                   f"{', '.join(suffixes)} (the {what} format follows it)")
        targets.append(target)
    return targets[0], targets[1]


def write_calibration_outputs(result: CalibrationResult, noise_path: str = "",
                              plot_path: str = "", overwrite: bool = False,
                              measured_at: str = "") -> tuple[str, str]:
    """The noise file (`noise.save_noise_file`) and the noise-characteristic plot (with the
    fit generalized to Sigma1..3) of a calibration; empty paths are skipped. Returns the
    paths written ('' for skipped ones). A file that cannot be written raises
    acquisition.DestinationError with the fit in its message, so the measurement is kept."""
    from .acquisition import DestinationError

    written = ["", ""]
    try:
        targets = check_calibration_outputs(noise_path, plot_path, overwrite)
        for target in targets:
            if target is not None:
                target.parent.mkdir(parents=True, exist_ok=True)
        _write_calibration_files(result, targets, measured_at, written)
    except (DestinationError, OSError) as exc:
        fit = result.model
        raise DestinationError(
            f"{exc}; the fit, not written: sigma_p2 = {fit.sigma_p2:.6g} (+-{result.stderr[0]:.2g}), "
            f"sigma_r2 = {fit.sigma_r2:.6g} (+-{result.stderr[1]:.2g}) at {fit.gain_db:g} dB, "
            f"{fit.exposure_ms:g} ms" + (f" (written: {', '.join(w for w in written if w)})"
                                          if any(written) else "")) from None
    return written[0], written[1]


def _write_calibration_files(result: CalibrationResult, targets, measured_at: str,
                             written: list) -> None:
    from .noise import save_noise_file

    s = result.settings
    if targets[0] is not None:
        measured = {"levels": int(s.levels), "frames_per_level": int(s.frames_per_level),
                    "leds_lit": [int(n) for n in result.leds_lit],
                    "image_size": [int(v) for v in result.image_shape],
                    "pixels_used": result.pixels_used,
                    "mean_range": [round(float(result.characteristic.pixel_mean.min()), 2),
                                   round(float(result.characteristic.pixel_mean.max()), 2)]}
        if measured_at:
            measured["at"] = measured_at
        save_noise_file(targets[0], result.model, result.stderr, measured)
        written[0] = str(targets[0])
    if targets[1] is not None:
        from .plots import plot_noise_characteristic
        plot_noise_characteristic(targets[1], result.characteristic, result.model,
                                  result.generalized())
        written[1] = str(targets[1])
