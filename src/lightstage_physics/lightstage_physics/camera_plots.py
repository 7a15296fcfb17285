"""Plots a user wants: the camera's noise characteristic and a sample relit by a few patterns.

matplotlib with the Agg backend; every function writes a PNG and returns its path.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .noise import NoiseModel
from .noise_fit import NoiseCharacteristic, bin_standard_errors
from .render import render_noisy
from .rig import CHANNELS, DEFAULT_DIMMER, N_SITES


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_noise_characteristic(path, characteristic: NoiseCharacteristic, fit: NoiseModel,
                              others: dict[str, NoiseModel] | None = None,
                              max_points: int = 4000, seed: int = 0) -> Path:
    """Measured (mean, variance) points, their binned means and the fitted affine line.

    The binned points are the fit's (`noise_fit.characteristic_from_moments`: binned by
    an independent half of the frames, so they scatter about the line without bias), with
    error bars of one standard error. `others` adds predicted lines, e.g. the fit
    generalized to the Sigma1..3 settings.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    rng = np.random.default_rng(seed)
    n = len(characteristic.pixel_mean)
    pick = rng.choice(n, min(n, max_points), replace=False)
    ax.scatter(characteristic.pixel_mean[pick], characteristic.pixel_var[pick], s=2,
               alpha=0.25, color="0.6", label="pixels (mean, variance)")
    ax.errorbar(characteristic.bin_mean, characteristic.bin_var,
                yerr=bin_standard_errors(characteristic, fit), fmt="o", ms=3,
                color="k", elinewidth=0.8, label="binned (+- 1 standard error)")
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
                      rng: np.random.Generator | None = None,
                      dimmer: float = DEFAULT_DIMMER) -> Path:
    """One sample under each column of `site_patterns` (8, k), one row per colour.

    Each image is stretched to its own 99.5th percentile, printed in its corner."""
    plt = _pyplot()
    rng = np.random.default_rng(0) if rng is None else rng
    W = np.asarray(site_patterns, dtype=float).reshape(N_SITES, -1)
    k = W.shape[1]
    images = render_noisy(modelset.subset([index]), W, noise, rng, dimmer=dimmer)[0]
    fig, axes = plt.subplots(len(CHANNELS), k, figsize=(1.9 * k + 0.4, 7.8), squeeze=False)
    for j in range(k):
        lit = "".join(str(int(v > 0)) for v in W[:, j])
        for c, channel in enumerate(CHANNELS):
            ax = axes[c, j]
            image = images[j * len(CHANNELS) + c]
            # each image stretched to its own range (single-LED images are dim); the
            # gray level shown as white is printed in the corner
            top = max(float(np.percentile(image, 99.5)), 1.0)
            ax.imshow(image, cmap="gray", vmin=0, vmax=top)
            ax.text(2, 10, f"{top:.0f}", color="yellow", fontsize=6)
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


def main(argv: list[str] | None = None) -> int:
    """`python -m lightstage_physics.camera_plots OUT_DIR [--capture FOLDER]`: example figures.

    Writes the noise characteristic of a simulated calibration at the paper's 15 dB / 30 ms
    fit (with the Sigma1..3 lines it generalizes to) and, with --capture, one sample relit
    by single sites, a lower/upper split and all sites at the chosen noise setting.
    """
    import argparse

    from .calibration_target import simulate_calibration_frames
    from .noise_fit import fit_noise_model, noise_characteristic
    from .noise import PAPER_CALIBRATION, SETTINGS, preset

    parser = argparse.ArgumentParser(prog="python -m lightstage_physics.camera_plots",
                                     description=main.__doc__.split("\n")[0])
    parser.add_argument("out_dir")
    parser.add_argument("--capture", help="capture folder for the relit-sample figure")
    parser.add_argument("--sample", type=int, default=0, help="sample index")
    parser.add_argument("--noise", default="sigma3")
    args = parser.parse_args(argv)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    frames = simulate_calibration_frames(PAPER_CALIBRATION, n_levels=8, n_frames=120,
                                         rng=np.random.default_rng(0))
    characteristic = noise_characteristic(frames)
    fit = fit_noise_model(characteristic)
    others = {name: fit.at(*setting) for name, setting in SETTINGS.items()}
    print(plot_noise_characteristic(out / "noise_characteristic.png", characteristic, fit,
                                    others))
    if args.capture:
        from .capture_format import load_capture
        ms = load_capture(args.capture, downscale_to=120)
        W = np.c_[np.eye(8)[:, [0, 4]], np.r_[np.ones(4), np.zeros(4)],
                  np.r_[np.zeros(4), np.ones(4)], np.ones(8)]
        print(plot_relit_sample(out / "relit_sample.png", ms, args.sample, W,
                                preset(args.noise)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
