"""Noise calibration on the stage: light a target at increasing levels, fit the noise model.

As in the paper: the target (a flat chart of smoothly varying reflectance) lies on the stage,
`calibration_patterns` light more and more LEDs (nested sets, the LEDs interleaved over
sites and colours so the light stays spread), many frames per level at one gain / exposure;
per-pixel moments of the two halves are accumulated frame by frame (`noise_fit.SplitMoments`)
and fitted (`noise_fit`). No rclpy: the acquisition node's CalibrateNoise action maps onto
`calibrate_noise`. Its files are written by `calibration_outputs`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from lightstage_graph.frames import mono16_to_gray
from lightstage_graph.limits import check_camera_setting
from lightstage_physics.errors import AcquisitionError, CaptureCancelled
from lightstage_physics.noise import SETTINGS, NoiseModel
from lightstage_physics.noise_fit import (MIN_FRAMES_PER_LEVEL, MIN_FRAMES_REASON,
                                          NoiseCharacteristic, SplitMoments,
                                          characteristic_from_moments, excess_scatter,
                                          fit_noise_model, fit_uncertainty)
from lightstage_physics.rig import N_CHANNELS, N_SITES

from .capture_settings import MAX_FRAMES_PER_REQUEST

__all__ = ["calibration_led_order", "calibration_patterns", "CalibrationSettings",
           "CalibrationResult", "calibrate_noise"]


def calibration_led_order(n_sites: int = N_SITES) -> list[int]:
    """LEDs in the order levels add them: every run of 4 has one LED of each colour, at
    sites spread around the stage (channel c, run r: site (r + 2c) mod n_sites)."""
    order = []
    for k in range(n_sites * N_CHANNELS):
        c, r = k % N_CHANNELS, k // N_CHANNELS
        order.append(((r + 2 * c) % n_sites) * N_CHANNELS + c)
    return order


def calibration_patterns(n_levels: int, n_sites: int = N_SITES) -> np.ndarray:
    """``(n_leds, n_levels)`` on/off patterns of increasing illumination: level i lights the
    first round(n_leds * i / n_levels) LEDs of `calibration_led_order` (nested sets; works on
    on/off and PWM stages alike). The last level lights every LED."""
    n_leds = n_sites * N_CHANNELS
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
    n_sites: int = N_SITES
    frames_per_request: int = 16

    def __post_init__(self) -> None:
        check_camera_setting(self.exposure_us, self.gain_db)  # LimitError (a ValueError)
        if int(self.frames_per_level) < MIN_FRAMES_PER_LEVEL:
            raise ValueError(f"frames_per_level must be >= {MIN_FRAMES_PER_LEVEL}, got "
                             f"{self.frames_per_level}: {MIN_FRAMES_REASON}")
        if not 2 <= int(self.levels) <= N_CHANNELS * int(self.n_sites):
            raise ValueError(f"levels must be 2..{N_CHANNELS * int(self.n_sites)}, got "
                             f"{self.levels}")
        if not 8 <= int(self.bit_depth) <= 16:
            raise ValueError(f"bit_depth must be 8..16, got {self.bit_depth}")
        if not 1 <= int(self.frames_per_request) <= MAX_FRAMES_PER_REQUEST:
            raise ValueError(f"frames_per_request must be 1..{MAX_FRAMES_PER_REQUEST}, got "
                             f"{self.frames_per_request}")

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
    `cancelled()` before each request (raises CaptureCancelled);
    `on_fitting()` once every frame is in, before the fit.
    """
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

