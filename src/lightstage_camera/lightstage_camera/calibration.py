"""Noise calibration: fit the affine noise model from frames of a target under several lights.

As in the paper: image a target of smoothly varying reflectance at increasing illumination,
many frames per level; every pixel gives one (mean, variance) point; a robust line through
the points gives variance = sigma_p2 * mean + sigma_r2 at the camera's current setting.
`NoiseModel.at` then generalizes it to other gains and exposures.
"""
from __future__ import annotations

from dataclasses import dataclass

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
    means, variances, n_frames = [], [], []
    for stack in _as_stacks(levels_frames):
        m = stack.mean(axis=0).ravel()
        v = stack.var(axis=0, ddof=1).ravel()
        sd = np.sqrt(v)
        keep = (m - clip_sigmas * sd > 0) & (m + clip_sigmas * sd < max_level)
        means.append(m[keep])
        variances.append(v[keep])
        n_frames.append(stack.shape[0])
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
    return NoiseCharacteristic(mean, var, bin_mean, bin_var, int(min(n_frames)))


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
    (n_levels, n_frames, H, W) works too), gray levels in camera units.
    """
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
