"""The camera noise model: affine variance, its generalization to other settings, sampling.

variance = sigma_p2 * mean + sigma_r2   (photon + read noise, in gray levels^2)
At gain G and exposure E, relative to the calibrated G0, E0 (gain in dB):
variance = (G/G0)^2 * ((E/E0) * sigma_p2 * mean + sigma_r2),  G/G0 = 10^((g_dB - g0_dB)/20)
Read noise depends only on gain; photon noise on gain and exposure.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


def gain_ratio(gain_db: float, reference_gain_db: float) -> float:
    """Linear amplitude gain ratio G/G0 of two gains given in dB."""
    return float(10.0 ** ((gain_db - reference_gain_db) / 20.0))


@dataclass(frozen=True)
class NoiseModel:
    """Affine noise model calibrated at `gain_db`, `exposure_ms` (defaults: the paper's fit)."""
    sigma_p2: float = 0.7
    sigma_r2: float = 66.0
    gain_db: float = 15.0
    exposure_ms: float = 30.0
    max_level: int = 1023

    def __post_init__(self) -> None:
        for name in ("sigma_p2", "sigma_r2"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        if not self.exposure_ms > 0:
            raise ValueError(f"exposure_ms must be > 0, got {self.exposure_ms}")
        if not self.max_level > 0:
            raise ValueError(f"max_level must be > 0, got {self.max_level}")

    def at(self, gain_db: float, exposure_ms: float) -> "NoiseModel":
        """The model generalized to another gain (dB) and exposure (ms)."""
        if not exposure_ms > 0:
            raise ValueError(f"exposure_ms must be > 0, got {exposure_ms}")
        g2 = gain_ratio(gain_db, self.gain_db) ** 2
        return replace(self, sigma_p2=g2 * (exposure_ms / self.exposure_ms) * self.sigma_p2,
                       sigma_r2=g2 * self.sigma_r2, gain_db=float(gain_db),
                       exposure_ms=float(exposure_ms))

    def variance(self, mean):
        """Per-pixel noise variance for noise-free gray levels `mean` (negative treated as 0)."""
        mean = np.asarray(mean)
        return self.sigma_p2 * np.maximum(mean, 0) + self.sigma_r2

    def sample(self, mean, rng: np.random.Generator, noise_scale: float = 1.0,
               out: np.ndarray | None = None) -> np.ndarray:
        """One noisy frame: Gaussian per pixel with the model's variance, clipped to the range.

        `noise_scale` multiplies the variance (the fast low-resolution path passes the
        downscale's variance factor). float32 throughout; `out` may alias `mean`.
        """
        mean = np.asarray(mean, dtype=np.float32)
        if noise_scale < 0:
            raise ValueError(f"noise_scale must be >= 0, got {noise_scale}")
        std = np.maximum(mean, np.float32(0))
        std *= np.float32(self.sigma_p2 * noise_scale)
        std += np.float32(self.sigma_r2 * noise_scale)
        np.sqrt(std, out=std)
        noisy = rng.standard_normal(mean.shape, dtype=np.float32)
        noisy *= std
        if out is None:
            out = noisy
            out += mean
        else:
            np.add(mean, noisy, out=out)
        return np.clip(out, 0, self.max_level, out=out)


# The paper's calibration (15 dB, 30 ms) and its three inference settings. The preset
# coefficients are the values printed in the paper; `NoiseModel().at(gain, exposure)` gives
# them from the 15 dB / 30 ms fit to within the rounding of that fit (see docs/PHYSICS.md).
PAPER_CALIBRATION = NoiseModel(0.7, 66.0, gain_db=15.0, exposure_ms=30.0)
SETTINGS: dict[str, tuple[float, float]] = {  # name -> (gain dB, exposure ms)
    "sigma1": (6.0, 84.0),
    "sigma2": (12.0, 42.0),
    "sigma3": (17.5, 22.5),
}
PRESETS: dict[str, NoiseModel] = {
    "sigma1": NoiseModel(0.25, 8.35, gain_db=6.0, exposure_ms=84.0),
    "sigma2": NoiseModel(0.50, 33.23, gain_db=12.0, exposure_ms=42.0),
    "sigma3": NoiseModel(0.94, 117.37, gain_db=17.5, exposure_ms=22.5),
}


def preset(name: str) -> NoiseModel | None:
    """A named noise setting: "sigma1".."sigma3", or "none" (returns None: noise-free)."""
    key = str(name).strip().lower()
    if key == "none":
        return None
    if key not in PRESETS:
        raise ValueError(f"unknown noise setting {name!r}; use one of "
                         f"{', '.join(list(PRESETS) + ['none'])}")
    return PRESETS[key]


def brightness_factor(gain_db: float, exposure_ms: float, reference_gain_db: float,
                      reference_exposure_ms: float) -> float:
    """How much brighter an image is at (gain, exposure) than at the reference setting."""
    return gain_ratio(gain_db, reference_gain_db) * exposure_ms / reference_exposure_ms


def choose_gain(images, exposure_ms: float, reference_gain_db: float,
                reference_exposure_ms: float, max_level: int = 1023,
                target_fraction: float = 0.9, percentile: float = 99.9,
                gain_range_db: tuple[float, float] = (0.0, 24.0)) -> float:
    """One camera gain (dB) for a whole pattern matrix at a fixed exposure.

    `images` are the matrix's noise-free renders at the reference setting (e.g. the capture's
    gain and exposure), any shape with images on the last two axes. The brightest image's
    `percentile` level is brought to `target_fraction * max_level`, so that the brightest
    image of the set just avoids saturation; the gain is clipped to the camera's range.
    """
    images = np.asarray(images, dtype=np.float32)
    if images.ndim < 2 or images.size == 0:
        raise ValueError("choose_gain needs at least one image (..., H, W)")
    if not 0 < target_fraction <= 1:
        raise ValueError(f"target_fraction must be in (0, 1], got {target_fraction}")
    flat = images.reshape(-1, images.shape[-2] * images.shape[-1])
    peak = float(np.max(np.percentile(flat, percentile, axis=1)))
    lo, hi = gain_range_db
    if peak <= 0:
        return float(hi)  # a black set: the most gain the camera has
    exposure_gain = exposure_ms / reference_exposure_ms
    wanted_ratio = target_fraction * max_level / (peak * exposure_gain)
    gain_db = reference_gain_db + 20.0 * np.log10(wanted_ratio)
    return float(np.clip(gain_db, lo, hi))
