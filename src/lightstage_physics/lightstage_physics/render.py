"""Relighting: the noise-free image under any illumination pattern is ``I = L @ w``.

Two modes:
- per colour (the paper's): a site pattern ``w`` (8,) is applied to each colour's 8
  single-site images, giving 4 images (R, G, B, NIR) per pattern column;
- joint (the paper's future work): an LED pattern ``p`` (32,) site-major mixes all
  LEDs into one image.
The authors' `dimmer` (`rig.DEFAULT_DIMMER`) scales the single-LED images so many lit LEDs
do not saturate.
Results are noise-free and unclipped; clipping belongs to the camera (`noise.NoiseModel`).
"""
from __future__ import annotations

import numpy as np

from .rig import DEFAULT_DIMMER, N_CHANNELS


def _model_array(models) -> np.ndarray:
    array = getattr(models, "models", models)  # accept a ModelSet or its array
    array = np.asarray(array)
    if array.ndim != 5 or array.shape[1] != N_CHANNELS:
        raise ValueError(f"models must be (n, {N_CHANNELS}, sites, H, W); got shape {array.shape}")
    if array.dtype != np.float32:
        array = array.astype(np.float32)
    return array


def validate_pattern_matrix(patterns, n_rows: int, what: str) -> np.ndarray:
    """A pattern matrix as float32 ``(n_rows, k)``; a 1-D vector is one column."""
    matrix = np.asarray(patterns, dtype=np.float64)
    if matrix.ndim == 1:
        matrix = matrix[:, None]
    if matrix.ndim != 2 or matrix.shape[0] != n_rows:
        raise ValueError(f"{what} must have shape ({n_rows}, k) (one column per pattern); "
                         f"got shape {np.shape(patterns)}")
    if matrix.shape[1] == 0:
        raise ValueError(f"{what} has no columns; give at least one pattern")
    if not np.all(np.isfinite(matrix)):
        bad = np.argwhere(~np.isfinite(matrix))[0]
        raise ValueError(f"{what} has a non-finite entry at row {bad[0]}, column {bad[1]}; "
                         "pattern entries must be numbers in [0, 1]")
    if matrix.min() < 0.0 or matrix.max() > 1.0:
        bad = np.argwhere((matrix < 0) | (matrix > 1))[0]
        raise ValueError(f"{what} entry at row {bad[0]}, column {bad[1]} is "
                         f"{matrix[bad[0], bad[1]]:g}; LED levels must lie in [0, 1]")
    return matrix.astype(np.float32)


def _validate_dimmer(dimmer: float) -> np.float32:
    if not np.isfinite(dimmer) or dimmer <= 0:
        raise ValueError(f"dimmer must be a positive number, got {dimmer}")
    return np.float32(dimmer)


def render_site_patterns(models, W, dimmer: float = DEFAULT_DIMMER) -> np.ndarray:
    """Per-colour relighting: ``(n, 4, 8, H, W)`` models and ``(8, k)`` site patterns.

    Returns float32 ``(n, 4*k, H, W)``; image ``j*4 + c`` is pattern column j in colour c
    (red, green, blue, nir).
    """
    array = _model_array(models)
    n, n_ch, n_sites, h, w = array.shape
    weights = validate_pattern_matrix(W, n_sites, "site pattern matrix W") * _validate_dimmer(dimmer)
    k = weights.shape[1]
    flat = array.reshape(n, n_ch, n_sites, h * w)
    out = np.matmul(weights.T, flat)                      # (n, 4, k, P)
    return np.ascontiguousarray(out.transpose(0, 2, 1, 3)).reshape(n, k * n_ch, h, w)


def led_to_channel_major(P) -> np.ndarray:
    """Reorder a site-major LED matrix ``(sites*4, k)`` to the models' channel-major rows."""
    P = np.asarray(P)
    n_sites = P.shape[0] // N_CHANNELS
    return P.reshape(n_sites, N_CHANNELS, -1).transpose(1, 0, 2).reshape(N_CHANNELS * n_sites, -1)


def render_led_patterns(models, P, dimmer: float = DEFAULT_DIMMER) -> np.ndarray:
    """Joint relighting: ``(n, 4, 8, H, W)`` models and ``(32, k)`` site-major LED patterns.

    Returns float32 ``(n, k, H, W)``, one image per pattern column.
    """
    array = _model_array(models)
    n, n_ch, n_sites, h, w = array.shape
    weights = validate_pattern_matrix(P, n_ch * n_sites, "LED pattern matrix P (site-major)")
    weights = led_to_channel_major(weights) * _validate_dimmer(dimmer)
    flat = array.reshape(n, n_ch * n_sites, h * w)
    return np.matmul(weights.T, flat).reshape(n, weights.shape[1], h, w)


def render_noisy(modelset, W, noise_model, rng: np.random.Generator, *, mode: str = "site",
                 dimmer: float = DEFAULT_DIMMER, brightness: float = 1.0) -> np.ndarray:
    """Relit images as the camera would record them: render, scale, add noise, clip.

    `mode` is "site" (W is (8, k), per colour) or "led" (W is (32, k), joint).
    The noise variance is scaled by the ModelSet's `noise_scale`, so a downscaled ModelSet
    gives the statistics of full-resolution noise followed by the same downscale.
    `noise_model=None` returns the clipped noise-free images.
    """
    if mode == "site":
        mean = render_site_patterns(modelset, W, dimmer)
    elif mode == "led":
        mean = render_led_patterns(modelset, W, dimmer)
    else:
        raise ValueError(f"mode must be 'site' or 'led', got {mode!r}")
    if brightness != 1.0:
        mean *= np.float32(brightness)
    noise_scale = float(getattr(modelset, "noise_scale", 1.0))
    if noise_model is None:
        max_level = getattr(getattr(modelset, "rig", None), "max_level", 1023)
        return np.clip(mean, 0, max_level, out=mean)
    return noise_model.sample(mean, rng, noise_scale=noise_scale, out=mean)
