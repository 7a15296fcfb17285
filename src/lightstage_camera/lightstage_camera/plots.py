"""Plots a user wants: the camera's noise characteristic and a sample relit by a few patterns.

matplotlib with the Agg backend; every function writes a PNG and returns its path.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .calibration import NoiseCharacteristic
from .noise import NoiseModel
from .render import render_noisy
from .rig import CHANNELS


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_noise_characteristic(path, characteristic: NoiseCharacteristic, fit: NoiseModel,
                              others: dict[str, NoiseModel] | None = None,
                              max_points: int = 4000, seed: int = 0) -> Path:
    """Measured (mean, variance) points, their binned means and the fitted affine line.

    `others` adds predicted lines, e.g. the fit generalized to the Sigma1..3 settings.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    rng = np.random.default_rng(seed)
    n = len(characteristic.pixel_mean)
    pick = rng.choice(n, min(n, max_points), replace=False)
    ax.scatter(characteristic.pixel_mean[pick], characteristic.pixel_var[pick], s=2,
               alpha=0.25, color="0.6", label="pixels (mean, variance)")
    ax.plot(characteristic.bin_mean, characteristic.bin_var, "o", ms=3, color="k",
            label="binned")
    x = np.linspace(0, fit.max_level, 100)
    ax.plot(x, fit.variance(x), "r-",
            label=f"fit: {fit.sigma_p2:.3g} I + {fit.sigma_r2:.3g} "
                  f"({fit.gain_db:g} dB, {fit.exposure_ms:g} ms)")
    for name, model in (others or {}).items():
        ax.plot(x, model.variance(x), "--",
                label=f"{name}: {model.sigma_p2:.2f} I + {model.sigma_r2:.2f}")
    ax.set_xlabel("mean gray level")
    ax.set_ylabel("variance (gray levels$^2$)")
    ax.set_xlim(0, fit.max_level)
    ax.set_title("camera noise characteristic")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_relit_sample(path, modelset, index: int, site_patterns, noise: NoiseModel | None,
                      rng: np.random.Generator | None = None, dimmer: float = 0.45) -> Path:
    """One sample under each column of `site_patterns` (8, k), one row per colour."""
    plt = _pyplot()
    rng = np.random.default_rng(0) if rng is None else rng
    W = np.asarray(site_patterns, dtype=float).reshape(8, -1)
    k = W.shape[1]
    images = render_noisy(modelset.subset([index]), W, noise, rng, dimmer=dimmer)[0]
    fig, axes = plt.subplots(len(CHANNELS), k, figsize=(1.9 * k + 0.4, 7.8), squeeze=False)
    vmax = modelset.max_level
    for j in range(k):
        lit = "".join(str(int(v > 0)) for v in W[:, j])
        for c, channel in enumerate(CHANNELS):
            ax = axes[c, j]
            ax.imshow(images[j * len(CHANNELS) + c], cmap="gray", vmin=0, vmax=vmax)
            ax.set_xticks([])
            ax.set_yticks([])
            if c == 0:
                ax.set_title(f"sites {lit}", fontsize=8)
            if j == 0:
                ax.set_ylabel(channel, fontsize=8)
    fig.suptitle(f"{modelset.sample_names[index]}, noise "
                 f"{'none' if noise is None else f'{noise.gain_db:g} dB {noise.exposure_ms:g} ms'}",
                 fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
