"""The differentiable twin of `render` and the affine camera noise, in JAX (float32).

Image formation is linear in the LED levels, so a gradient of anything computed from the
images reaches the levels: for an LED pattern matrix ``P`` (32, k), site-major like
`render.render_led_patterns` and `mux_trainer.rendering.clean_led_images`,

    mean_j  = sum_i P[i, j] * dimmer * model_i                     (relight)
    noisy_j = clip(mean_j + sqrt(a * max(mean_j, 0) + b) * eps_j, 0, max_level)

with ``eps`` standard normals drawn afresh by the caller (the reparameterisation: the noise's
variance follows the levels, and its gradient with it). ``a`` and ``b`` are the variance
coefficients at the resolution rendered (`SearchData.noise_a/noise_b`: the camera's
sigma_p^2 and sigma_r^2 times the downscale's `noise_scale`), so rendering at the
classifier's 120 px is the camera's full-resolution noise followed by the downscale. The
clip passes the gradient where it does not bind (zero where a pixel saturates or is black).

JAX is imported here only: the rest of the package, the classifier node and the numpy
renderer never need it.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .rig import DEFAULT_DIMMER, N_CHANNELS

__all__ = ["led_basis", "relight", "add_noise", "render_noisy"]


def led_basis(models, dimmer: float = DEFAULT_DIMMER) -> jnp.ndarray:
    """ModelSet-shaped models ``(n, 4, sites, H, W)`` -> float32 ``(sites * 4, n, H * W)``,
    site-major LED rows (row ``site * 4 + channel``), dimmer applied: the layout of
    `SearchData.basis` reshaped to ``(32, n, pixels)``."""
    array = np.asarray(getattr(models, "models", models), dtype=np.float32)
    if array.ndim != 5 or array.shape[1] != N_CHANNELS:
        raise ValueError(f"models must be (n, {N_CHANNELS}, sites, H, W); got shape {array.shape}")
    if not np.isfinite(dimmer) or dimmer <= 0:
        raise ValueError(f"dimmer must be a positive number, got {dimmer}")
    n, C, S, H, W = array.shape
    basis = array.transpose(2, 1, 0, 3, 4).reshape(S * C, n, H * W) * np.float32(dimmer)
    return jnp.asarray(basis, dtype=jnp.float32)


def relight(basis: jnp.ndarray, P: jnp.ndarray) -> jnp.ndarray:
    """Noise-free images ``(k, n, pixels)`` of LED patterns ``P`` (LEDs, k) on a basis
    ``(LEDs, n, pixels)`` (`led_basis`, or `SearchData.basis` reshaped)."""
    L, n, p = basis.shape
    if P.shape[0] != L:
        raise ValueError(f"pattern matrix has {P.shape[0]} rows but the basis {L} LEDs")
    out = jnp.tensordot(P.astype(jnp.float32), basis.reshape(L, n * p), axes=([0], [0]))
    return out.reshape(P.shape[1], n, p)


def add_noise(mean: jnp.ndarray, eps: jnp.ndarray, a: float, b: float,
              max_level: float) -> jnp.ndarray:
    """``clip(mean + sqrt(a * max(mean, 0) + b) * eps, 0, max_level)`` in float32 (the
    numpy `rendering.add_noise` on the same normals). The variance is kept off zero inside
    the square root so its gradient stays finite where ``a * mean + b`` is 0."""
    var = jnp.maximum(mean, 0.0) * jnp.float32(a) + jnp.float32(b)
    std = jnp.sqrt(jnp.maximum(var, jnp.float32(1e-12)))
    return jnp.clip(mean + std * eps, 0.0, jnp.float32(max_level))


def render_noisy(basis: jnp.ndarray, P: jnp.ndarray, key: jax.Array, a: float, b: float,
                 max_level: float) -> jnp.ndarray:
    """Relit images with a fresh noise draw from ``key``: ``(k, n, pixels)`` float32."""
    mean = relight(basis, P)
    eps = jax.random.normal(key, mean.shape, dtype=jnp.float32)
    return add_noise(mean, eps, a, b, max_level)
