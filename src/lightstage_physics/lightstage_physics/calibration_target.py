"""The calibration target: a flat chart of smoothly varying reflectance, simulated.

`calibration_target` is its reflectance; `simulate_calibration_frames` draws frames of it
from a noise model (for the fit's tests and examples); `write_calibration_target` writes it
as a capture folder the simulated camera can put on the stage (`lightstage synth
--calibration-target`).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from .capture_format import RIG_FILE, write_pose
from .noise import NoiseModel
from .rig import DEFAULT_DIMMER, N_CHANNELS, N_SITES, Rig

__all__ = ["calibration_target", "simulate_calibration_frames", "write_calibration_target",
           "CALIBRATION_TARGET_NAME"]

CALIBRATION_TARGET_NAME = "calibration-target/s0/p00"


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


def write_calibration_target(out_dir, shape=(48, 64), n_sites: int = N_SITES,
                             peak_level: float | None = None, dimmer: float = DEFAULT_DIMMER,
                             bit_depth: int = 10, overwrite: bool = False) -> Path:
    """A capture folder holding one sample, ``calibration-target/s0/p00``: the flat chart of
    `calibration_target` (smooth reflectance ramp) under each single LED.

    Each LED lights it with its own strength (per colour and upper/lower site) and a gentle
    gradient from its side of the stage. All LEDs together, scaled by the simulated camera's
    `dimmer`, bring the brightest pixel to `peak_level` (default 1.1 x the camera's maximum:
    the brightest calibration level saturates its top end, as in the paper's curves).
    """
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
    images = np.zeros((N_CHANNELS, n_sites, h, w))
    for s in range(n_sites):
        az = math.atan2(positions[s, 1], positions[s, 0])
        gradient = 1.0 + 0.15 * (np.cos(az) * xx + np.sin(az) * yy)
        strength = 1.0 if s >= n_sites // 2 else 0.7
        for c in range(N_CHANNELS):
            images[c, s] = reflectance * gradient * strength * colour[c]
    images *= peak / (dimmer * images.sum(axis=(0, 1)).max())
    if images.max() > max_level:
        raise ValueError(f"peak_level {peak:g} at dimmer {dimmer:g} needs single-LED images "
                         f"brighter than the camera's maximum; lower peak_level")
    out.mkdir(parents=True, exist_ok=True)
    rig.save_yaml(out / RIG_FILE)
    write_pose(out / CALIBRATION_TARGET_NAME, images.astype(np.float32), rig.bit_depth)
    return out
