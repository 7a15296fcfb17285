"""Noise calibration: fit the affine noise model from frames of a target under several lights.

As in the paper: image a target of smoothly varying reflectance at increasing illumination,
many frames per level; every pixel gives (mean, variance) points; a robust line through
the binned points gives variance = sigma_p2 * mean + sigma_r2 at the camera's current setting.
`NoiseModel.at` then generalizes it to other gains and exposures.

Unbiased for any frame count >= 3 (docs/PHYSICS.md, "Noise calibration"): each level's
frames are split into two interleaved halves (even and odd frames); a pixel's point is the
mean and unbiased variance of one half, and it is binned, and kept or dropped near 0 and
saturation, by the mean of the *other* half against the fitted model's noise. What decides a
point's bin and whether it is used is then independent of the point itself, so neither the
binning nor the dropping selects points by their own noise (the old rule, dropping a pixel
whose own sample sd put it near 0, kept only the low-variance pixels at low means and bent
the binned points below the line there, the more the fewer the frames: issue 12 item 6).

Acquisition on the stage (`calibrate_noise`, no rclpy; the acquisition node's CalibrateNoise
action maps onto it): the target lies on the stage, `calibration_patterns` light more and
more LEDs (nested sets, the LEDs interleaved over sites and colours so the light stays
spread), many frames per level at one gain / exposure; per-pixel moments of the two halves
are accumulated frame by frame (`SplitMoments`), so no frame stack is held in memory.
`fit_uncertainty` gives the fit's standard errors from the degrees of freedom in each bin;
`write_calibration_target` writes a target as a capture folder the simulated camera can put
on the stage.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .noise import NoiseModel

# fewest frames per level: a variance needs 2 frames of one half, a bin key 1 of the other
MIN_FRAMES_PER_LEVEL = 3
MIN_FRAMES_REASON = (f"the fit needs at least {MIN_FRAMES_PER_LEVEL} frames per level: the "
                     "frames are split into two interleaved halves, a pixel's variance comes "
                     "from one half (2 frames at least) and the bin it goes in from the other "
                     "(1 at least), which keeps the fit unbiased")
# the line fit's Huber loss: residuals beyond 3 standard errors count linearly, so clean
# bins are fitted as by weighted least squares and only grossly stray ones are held back.
# The usual 1.35 pulls toward the median of a bin's skewed (chi^2) mean of variances when the
# bin holds few degrees of freedom (measured over 400 seeds at 4 frames per level: sigma_r2
# -0.20 se with 1.35, -0.17 with 3, the same frames; not significant at other counts).
HUBER_EPSILON = 3.0


@dataclass
class NoiseCharacteristic:
    """Per-pixel statistics of a calibration capture, binned along the mean.

    The bins hold half-level points (one half's mean and unbiased variance of a pixel),
    binned by the other half's mean; a bin's mean and variance are averages weighted by the
    points' degrees of freedom, which `bin_dof` sums (its variance's standard error is
    sqrt(2 / bin_dof) times the variance for Gaussian noise).
    """
    pixel_mean: np.ndarray  # every used pixel's mean over all its level's frames (display)
    pixel_var: np.ndarray  # and its unbiased variance over them (display)
    bin_mean: np.ndarray  # dof-weighted mean of the points' means in each bin
    bin_var: np.ndarray  # dof-weighted mean of their unbiased variances (unlike a median)
    bin_dof: np.ndarray  # degrees of freedom of the variances averaged in each bin
    n_frames: int  # fewest frames of a level


HalfMoments = tuple  # (mean (H, W), unbiased variance (H, W) or None, frames)


def _check_frames(n_frames: int, where: str) -> None:
    if int(n_frames) < MIN_FRAMES_PER_LEVEL:
        raise ValueError(f"{where}: {int(n_frames)} frames; {MIN_FRAMES_REASON}")


def _half_moments(stack: np.ndarray) -> HalfMoments:
    n = stack.shape[0]
    return stack.mean(axis=0), (stack.var(axis=0, ddof=1) if n >= 2 else None), n


def _as_stacks(levels_frames) -> list[np.ndarray]:
    stacks = [np.asarray(f, dtype=np.float64) for f in levels_frames]
    if not stacks:
        raise ValueError("no calibration levels given; pass one (n_frames, H, W) stack per level")
    for i, s in enumerate(stacks):
        if s.ndim < 2:
            raise ValueError(f"level {i}: need a stack of frames (n_frames, H, W), got shape "
                             f"{s.shape}")
        _check_frames(s.shape[0], f"level {i}")
    return stacks


def noise_characteristic(levels_frames, max_level: int = 1023, n_bins: int = 60,
                         clip_sigmas: float = 4.0) -> NoiseCharacteristic:
    """Binned (mean, variance) points of frame stacks, one (n_frames >= 3, H, W) per level.

    Each level's even and odd frames are the two halves (`characteristic_from_moments`).
    """
    halves = [(_half_moments(s[0::2]), _half_moments(s[1::2])) for s in _as_stacks(levels_frames)]
    return characteristic_from_moments(halves, max_level, n_bins, clip_sigmas)


def characteristic_from_moments(levels, max_level: int = 1023, n_bins: int = 60,
                                clip_sigmas: float = 4.0) -> NoiseCharacteristic:
    """`noise_characteristic` from per-level half moments: one pair of halves per level, each
    ``(pixel mean, unbiased variance or None, frames)`` (`SplitMoments.halves`).

    Each half with >= 2 frames gives every pixel a point (its mean, its variance, frames - 1
    degrees of freedom) keyed by the other half's mean. A point is used when its key lies
    `clip_sigmas` noise sds (the fitted model's, widened by 1 + 1/sqrt(frames) for the key's
    own noise) clear of 0 and `max_level`, where clipping would shrink the variance; since
    the model comes from the fit, fit and selection alternate (dropping points, never taking
    them back) until no more points drop. The used points are binned by key into `n_bins`
    quantile bins. The selection depends on a point only through its key, never its own
    mean or variance, so it cannot bias the bins.
    """
    points = _points(levels)
    if points["key"].size == 0:
        raise ValueError("no calibration levels given; pass one (n_frames, H, W) stack per level")
    # Start from every point whose key is inside the range and only ever drop points, so
    # that the selection settles (a selection that could take points back can cycle).
    used = (points["key"] > 0) & (points["key"] < max_level)
    for _ in range(100):
        slope, intercept = fit_line_robust(*_binned(points, used, n_bins))
        model_sd = np.sqrt(np.maximum(slope * np.maximum(points["key"], 0) + intercept, 0.0))
        margin = clip_sigmas * model_sd * (1.0 + 1.0 / np.sqrt(points["key_frames"]))
        kept = used & (points["key"] - margin > 0) & (points["key"] + margin < max_level)
        if np.array_equal(kept, used):
            break
        used = kept
    bin_mean, bin_var, bin_dof = _binned(points, used, n_bins)
    pixel_mean, pixel_var = _pixel_moments(levels)
    pixels = np.unique(points["pixel"][used])
    frames = min(int(a[2]) + int(b[2]) for a, b in levels)
    return NoiseCharacteristic(pixel_mean[pixels], pixel_var[pixels], bin_mean, bin_var,
                               bin_dof, frames)


def _points(levels) -> dict[str, np.ndarray]:
    """Every half-level point: key (other half's mean), mean, var, dof, key_frames, pixel."""
    parts: dict[str, list] = {k: [] for k in ("key", "mean", "var", "dof", "key_frames", "pixel")}
    offset = 0
    for i, halves in enumerate(levels):
        (ma, va, na), (mb, vb, nb) = halves
        _check_frames(int(na) + int(nb), f"level {i}")
        size = np.asarray(ma).size
        for (km, _, kn), (m, v, n) in (((ma, va, na), (mb, vb, nb)), ((mb, vb, nb), (ma, va, na))):
            if int(n) < 2:
                continue
            parts["key"].append(np.asarray(km, np.float64).ravel())
            parts["mean"].append(np.asarray(m, np.float64).ravel())
            parts["var"].append(np.asarray(v, np.float64).ravel())
            parts["dof"].append(np.full(size, int(n) - 1, np.float64))
            parts["key_frames"].append(np.full(size, int(kn), np.float64))
            parts["pixel"].append(offset + np.arange(size))
        offset += size
    if not parts["key"]:
        return {k: np.zeros(0) for k in parts}
    return {k: np.concatenate(v) for k, v in parts.items()}


def _binned(points, used, n_bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, variance, dof) of the used points in `n_bins` quantile bins of their keys."""
    if int(used.sum()) < 10:
        raise ValueError("fewer than 10 usable pixels: every level is saturated or black; "
                         "use illumination levels that span the camera's range")
    key, dof = points["key"][used], points["dof"][used]
    edges = np.unique(np.quantile(key, np.linspace(0, 1, n_bins + 1)))
    n = max(len(edges) - 1, 1)
    which = np.clip(np.searchsorted(edges, key, side="right") - 1, 0, n - 1)
    bin_dof = np.bincount(which, dof, n)
    ok = bin_dof > 0
    return (np.bincount(which, dof * points["mean"][used], n)[ok] / bin_dof[ok],
            np.bincount(which, dof * points["var"][used], n)[ok] / bin_dof[ok], bin_dof[ok])


def _pixel_moments(levels) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's mean and unbiased variance over all frames of its level, from halves."""
    means, variances = [], []
    for (ma, va, na), (mb, vb, nb) in levels:
        ma, mb = np.asarray(ma, np.float64).ravel(), np.asarray(mb, np.float64).ravel()
        n = na + nb
        within = sum((k - 1) * np.asarray(v, np.float64).ravel()
                     for v, k in ((va, na), (vb, nb)) if k >= 2)
        means.append((na * ma + nb * mb) / n)
        variances.append((within + na * nb / n * (ma - mb) ** 2) / (n - 1))
    return np.concatenate(means), np.concatenate(variances)


def fit_line_robust(x: np.ndarray, y: np.ndarray, dof: np.ndarray) -> tuple[float, float]:
    """Slope and intercept of a line through binned variances, robust to stray bins.

    `y` are means of variances with `dof` degrees of freedom behind each, so with Gaussian
    frames their standard errors are sqrt(2 / dof) times the line at x. The residuals,
    scaled by those, go through a Huber loss (quadratic within `HUBER_EPSILON`, linear
    beyond): weighted least squares on clean bins, bounded pull from a stray one. Solved by
    iteratively reweighted least squares, the standard errors following the line.
    """
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    dof = np.asarray(dof, np.float64)
    scale = float(np.max(np.abs(x))) or 1.0  # conditioning: x in [0, 1]
    design = np.column_stack([x / scale, np.ones_like(x)])
    line = y.copy()  # start: the bins' own values (only to begin the standard errors)
    floor = 1e-9 * max(1.0, float(np.max(np.abs(y))))
    weight = np.ones_like(x)
    coef = np.zeros(2)
    for _ in range(100):
        se = np.sqrt(2.0 / dof) * np.maximum(line, floor)
        root = np.sqrt(weight) / se
        new, *_ = np.linalg.lstsq(design * root[:, None], y * root, rcond=None)
        line = design @ new
        r = np.abs(y - line) / (np.sqrt(2.0 / dof) * np.maximum(line, floor))
        weight = np.minimum(1.0, HUBER_EPSILON / np.maximum(r, 1e-12))
        if np.allclose(new, coef, rtol=1e-10, atol=1e-12 * float(np.max(np.abs(y)) or 1.0)):
            break
        coef = new
    return float(new[0] / scale), float(new[1])

def fit_noise_model(levels_frames, gain_db: float = 15.0, exposure_ms: float = 30.0,
                    max_level: int = 1023) -> NoiseModel:
    """The affine noise model at the capture's (gain, exposure) from calibration frames.

    `levels_frames`: one array (n_frames >= 3, H, W) per illumination level (an array
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
    slope, intercept = fit_line_robust(char.bin_mean, char.bin_var, char.bin_dof)
    if slope < 0 or intercept < 0:
        raise ValueError(f"fitted a negative noise term (sigma_p2={slope:.3g}, "
                         f"sigma_r2={intercept:.3g}); check the frames are of a static scene")
    return NoiseModel(slope, intercept, gain_db=gain_db, exposure_ms=exposure_ms,
                      max_level=max_level)


def bin_standard_errors(char: NoiseCharacteristic, fit: NoiseModel) -> np.ndarray:
    """Standard error of each bin's variance: a variance from k Gaussian frames has variance
    2 sigma^4 / (k - 1), a bin's average of points with d degrees of freedom in all
    2 sigma^4 / d, sigma^2 the fitted variance at the bin's mean."""
    return fit.variance(np.asarray(char.bin_mean, np.float64)) * np.sqrt(2.0 / char.bin_dof)


def standardized_residuals(char: NoiseCharacteristic, fit: NoiseModel) -> np.ndarray:
    """Each bin's variance minus the fitted line, in its standard errors; about N(0, 1) when
    the model holds."""
    return (np.asarray(char.bin_var) - fit.variance(char.bin_mean)) / bin_standard_errors(char, fit)


def fit_uncertainty(char: NoiseCharacteristic, fit: NoiseModel) -> tuple[float, float]:
    """Standard errors of (sigma_p2, sigma_r2) of a fit to `char`, from its bins' dofs.

    The fit is weighted least squares with the bins' variances (`bin_standard_errors`)
    under a Huber loss, so its covariance is (X' W X)^-1 times Huber's factor
    E[psi^2] / E[psi']^2 of the standardized residuals (1.00 on clean data, more when bins
    stray). tests/acquisition/test_calibration_coverage.py checks over many simulated
    calibrations and frame counts that the configured noise falls inside +-1 and +-2 of
    these standard errors at the normal rates (68.3 %, 95.4 %).
    """
    x = np.asarray(char.bin_mean, np.float64)
    design = np.column_stack([x, np.ones_like(x)]) / bin_standard_errors(char, fit)[:, None]
    r = np.abs(standardized_residuals(char, fit))
    inside = max(float(np.mean(r <= HUBER_EPSILON)), 0.1)
    factor = float(np.mean(np.minimum(r, HUBER_EPSILON) ** 2)) / inside ** 2
    cov = np.linalg.inv(design.T @ design) * factor
    return float(math.sqrt(cov[0, 0])), float(math.sqrt(cov[1, 1]))


def excess_scatter(char: NoiseCharacteristic, fit: NoiseModel) -> float:
    """How many times wider the bins scatter about the line than Gaussian frame noise
    explains (robust: 1.4826 x the median absolute standardized residual); about 1 when the
    model holds, more for a moving target, flicker or pixels with extra noise."""
    return float(1.4826 * np.median(np.abs(standardized_residuals(char, fit))))


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

    def moments(self) -> HalfMoments:
        """(mean, unbiased variance or None below 2 frames, frames)."""
        return self.mean(), (self.variance() if self.count >= 2 else None), self.count


class SplitMoments:
    """`PixelMoments` of a level's even and odd frames (the two halves the fit needs)."""

    def __init__(self):
        self.halves = (PixelMoments(), PixelMoments())
        self.count = 0

    def add(self, gray: np.ndarray) -> None:
        self.halves[self.count % 2].add(gray)
        self.count += 1

    def moments(self) -> tuple[HalfMoments, HalfMoments]:
        """The halves' moments, for `characteristic_from_moments`."""
        if self.count < MIN_FRAMES_PER_LEVEL:
            raise ValueError(f"{self.count} frames; {MIN_FRAMES_REASON}")
        return self.halves[0].moments(), self.halves[1].moments()

    def mean(self) -> np.ndarray:
        a, b = self.halves
        return (a.count * a.mean() + b.count * b.mean()) / self.count


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
        if int(self.frames_per_level) < MIN_FRAMES_PER_LEVEL:
            raise ValueError(f"frames_per_level must be >= {MIN_FRAMES_PER_LEVEL}, got "
                             f"{self.frames_per_level}: {MIN_FRAMES_REASON}")
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
        scatter = excess_scatter(self.characteristic, self.model)
        if scatter > 1.5:
            out.append(f"the binned variances scatter {scatter:.1f} times more about the fitted "
                       "line than frame-to-frame noise explains (a target that moved, flickering "
                       "light, pixels with extra noise?), so the stated standard errors are too "
                       "small: check the stage and calibrate again")
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
        acc = SplitMoments()
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
        moments.append(acc.moments())
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
