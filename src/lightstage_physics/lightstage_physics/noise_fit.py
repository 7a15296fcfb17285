"""The noise fit: the affine noise model from frames of a target under several lights.

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
the binned points below the line there, the more the fewer the frames).

`PixelMoments` / `SplitMoments` accumulate the halves' per-pixel moments frame by frame, so no
frame stack is held in memory; `fit_uncertainty` gives the fit's standard errors from the
degrees of freedom in each bin. The calibration on the stage is `calibration`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

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
    stray). tests/lightstage_camera/acquisition/test_calibration_coverage.py checks over many simulated
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
