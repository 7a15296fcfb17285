"""The camera noise model: affine variance, its generalization to other settings, sampling.

variance = sigma_p2 * mean + sigma_r2   (photon + read noise, in gray levels^2)
At gain G and exposure E, relative to the calibrated G0, E0 (gain in dB):
variance = (G/G0)^2 * ((E/E0) * sigma_p2 * mean + sigma_r2),  G/G0 = 10^((g_dB - g0_dB)/20)
Read noise depends only on gain; photon noise on gain and exposure.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lightstage_graph.limits import (EXPOSURE_US_MAX, EXPOSURE_US_MIN, check_gain_db,
                                     check_range)

from .errors import NoiseFileError

# The largest noise any file, artifact or setting may describe: a standard deviation of the
# whole 16-bit range (read noise), or of it at full scale (photon noise). Far above any
# camera (the paper's 0.7 and 66 at 15 dB); 1e300 is a typo, not a camera.
MAX_SIGMA_P2 = 65535.0
MAX_SIGMA_R2 = 65535.0 ** 2
EXPOSURE_MS_RANGE = (EXPOSURE_US_MIN / 1000.0, EXPOSURE_US_MAX / 1000.0)


def check_noise_coefficients(sigma_p2, sigma_r2, gain_db, exposure_ms, what: str = "{}") -> None:
    """Refuse a noise model's values out of range (ValueError naming the field as
    `what.format(name)`): sigma_p2 0 .. MAX_SIGMA_P2, sigma_r2 0 .. MAX_SIGMA_R2, gain_db
    in the shared gain range, exposure_ms in the shared exposure range."""
    check_range(sigma_p2, what.format("sigma_p2"), 0.0, MAX_SIGMA_P2)
    check_range(sigma_r2, what.format("sigma_r2"), 0.0, MAX_SIGMA_R2)
    check_gain_db(gain_db, what.format("gain_db"), nan_is_default=False)
    check_range(exposure_ms, what.format("exposure_ms"), *EXPOSURE_MS_RANGE, "ms")


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


# ---- calibrated noise files ----------------------------------------------------------
# A noise file is the YAML `lightstage calibrate` writes: the fitted model at the setting it
# was measured at, with its standard errors and how it was measured. `load_noise_file` gives
# the NoiseModel back; `noise_setting` accepts a preset name or such a file.
NOISE_FILE_KIND = "lightstage-noise-calibration"
NOISE_FILE_VERSION = 1


def save_noise_file(path, model: NoiseModel, stderr: tuple[float, float] | None = None,
                    measured: dict | None = None) -> Path:
    """Write `model` (and its standard errors, how it was measured) as a noise YAML file.

    The write is atomic (a temporary file renamed over the target)."""
    import os

    import yaml

    doc = {"kind": NOISE_FILE_KIND, "version": NOISE_FILE_VERSION,
           "noise_model": {"sigma_p2": float(model.sigma_p2), "sigma_r2": float(model.sigma_r2),
                           "gain_db": float(model.gain_db),
                           "exposure_ms": float(model.exposure_ms),
                           "max_level": int(model.max_level)}}
    if stderr is not None:
        doc["stderr"] = {"sigma_p2": float(stderr[0]), "sigma_r2": float(stderr[1])}
    doc["generalized"] = {name: {"gain_db": g, "exposure_ms": e,
                                 "sigma_p2": round(float(model.at(g, e).sigma_p2), 6),
                                 "sigma_r2": round(float(model.at(g, e).sigma_r2), 6)}
                          for name, (g, e) in SETTINGS.items()}
    if measured:
        doc["measured"] = measured
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    header = ("# Camera noise calibration: variance = sigma_p2 * mean + sigma_r2 (gray levels^2)\n"
              "# at gain_db / exposure_ms; other settings: NoiseModel.at (docs/PHYSICS.md).\n"
              "# Written by `lightstage calibrate`; use it as the sim camera's noise_file.\n")
    try:
        tmp.write_text(header + yaml.safe_dump(doc, sort_keys=False))
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def load_noise_file(path) -> NoiseModel:
    """The NoiseModel of a noise file written by `save_noise_file`; NoiseFileError if bad."""
    from pathlib import Path

    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise NoiseFileError(f"{path}: cannot read the noise file ({exc.strerror or exc}); "
                             "give a file written by `lightstage calibrate`") from None
    except UnicodeDecodeError:
        raise NoiseFileError(f"{path}: not a text file, so not a noise calibration file; give "
                             "a YAML file written by `lightstage calibrate`") from None
    except yaml.YAMLError as exc:
        raise NoiseFileError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(doc, dict) or doc.get("kind") != NOISE_FILE_KIND:
        raise NoiseFileError(f"{path}: not a noise calibration file (expected kind: "
                             f"{NOISE_FILE_KIND}); write one with `lightstage calibrate`")
    if doc.get("version") != NOISE_FILE_VERSION:
        raise NoiseFileError(f"{path}: noise file version {doc.get('version')!r}, this "
                             f"version reads {NOISE_FILE_VERSION}")
    m = doc.get("noise_model")
    keys = ("sigma_p2", "sigma_r2", "gain_db", "exposure_ms")
    if not isinstance(m, dict):
        raise NoiseFileError(f"{path}: it has no noise_model mapping ({', '.join(keys)}); "
                             "write the file with `lightstage calibrate`")
    missing = [k for k in keys if k not in m]
    unknown = sorted(set(m) - {*keys, "max_level"})
    if missing or unknown:
        raise NoiseFileError(f"{path}: noise_model needs {', '.join(keys)} (and may give "
                             f"max_level); {'missing ' + ', '.join(missing) if missing else ''}"
                             f"{'; ' if missing and unknown else ''}"
                             f"{'unknown ' + ', '.join(unknown) if unknown else ''}")
    try:
        check_noise_coefficients(*(_yaml_float(m[k], f"noise_model.{k}") for k in keys),
                                 what="noise_model.{}")
        max_level = m.get("max_level", 1023)
        if isinstance(max_level, bool) or not isinstance(max_level, int) or not 1 <= max_level <= 65535:
            raise ValueError(f"noise_model.max_level must be a whole number 1 .. 65535, got "
                             f"{max_level!r}")
        return NoiseModel(*(float(m[k]) for k in ("sigma_p2", "sigma_r2")),
                          gain_db=float(m["gain_db"]), exposure_ms=float(m["exposure_ms"]),
                          max_level=max_level)
    except ValueError as exc:
        raise NoiseFileError(f"{path}: {exc}") from None


def _yaml_float(value, what: str) -> float:
    """A number of a YAML file (YAML 1.1 reads 3e4 as a string: taken); ValueError naming
    `what` for anything else (`gain_db: loud`)."""
    if not isinstance(value, bool):
        try:
            return float(value)
        except (TypeError, ValueError, OverflowError):
            pass
    raise ValueError(f"{what} must be a number, got {value!r}")


def noise_setting(spec) -> NoiseModel | None:
    """A noise setting by name ("sigma1".."sigma3", "none") or a calibrated noise file
    (a path ending in .yaml / .yml): the file's model as measured, at its own setting."""
    text = str(spec).strip()
    if text.lower().endswith((".yaml", ".yml")):
        return load_noise_file(text)
    return preset(text)
