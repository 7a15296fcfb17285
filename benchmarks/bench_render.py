"""Relit-and-noised 120 x 120 images per second: fast low-resolution path vs full resolution.

Full-resolution path (what the paper's code does): render I = L @ w at full resolution,
add camera noise per full-resolution pixel, clip, block-mean downscale to 120 x 120.
Fast path: downscale the models once (ModelSet.downscaled), then render at 120 x 120 and
add noise whose variance is scaled by the downscale's factor (noise_scale). Both produce
the same statistics away from saturation (tests/lightstage_physics/test_lowres.py).

    .venv/bin/python benchmarks/bench_render.py [--size 240] [--agreement DRAWS]
    .venv/bin/python benchmarks/bench_render.py --quick   # 4 samples, 1 run, 20 draws
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from lightstage_physics.noise import preset
from lightstage_physics.render import render_noisy
from lightstage_physics.rig import Rig
from lightstage_physics.scene_models import ModelSet

from _common import parse_args


def make_models(n: int, size: int, seed: int = 0) -> ModelSet:
    rng = np.random.default_rng(seed)
    models = rng.uniform(0, 120, size=(n, 4, 8, size, size)).astype(np.float32)
    return ModelSet(models, np.zeros(n, int), ["x-real"], [f"m{i}" for i in range(n)],
                    np.arange(n), np.zeros(n, int), Rig.paper_default(size))


def best_rate(fn, n_images: int, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return n_images / best


def agreement(size: int, reps: int, noise_name: str) -> None:
    """Per-pixel mean/variance agreement of the two paths over `reps` noise draws."""
    from scipy import ndimage, stats

    noise = preset(noise_name)
    rng = np.random.default_rng(5)
    field = ndimage.gaussian_filter(rng.standard_normal((2, 4, 8, size, size)), (0, 0, 0, 8, 8))
    full = make_models(2, size)
    full.models[:] = 15 + 110 * (field - field.min()) / np.ptp(field)
    small = full.downscaled(120)
    W = np.eye(8)[:, [0, 3]] + np.eye(8)[:, [5, 6]]
    f = size // 120
    fast = np.stack([render_noisy(small, W, noise, rng) for _ in range(reps)])
    slow = np.stack([render_noisy(full, W, noise, rng).reshape(2, 8, 120, f, 120, f)
                     .mean(axis=(3, 5)) for _ in range(reps)])
    m1, m2, v1, v2 = fast.mean(0), slow.mean(0), fast.var(0, ddof=1), slow.var(0, ddof=1)
    sd = np.sqrt(noise.variance(np.clip(m2, 0, None)))
    ok = (m2 - 4 * sd > 0) & (m2 + 4 * sd < noise.max_level)
    z = (m1 - m2) / np.sqrt((v1 + v2) / reps)
    ratio = v1[ok] / v2[ok]
    p_var = 2 * np.minimum(stats.f.cdf(ratio, reps - 1, reps - 1), stats.f.sf(ratio, reps - 1, reps - 1))
    print(f"agreement over {reps} draws, {ok.sum()} pixels away from clipping "
          f"({size} -> 120 px, {noise_name}):")
    print(f"  mean difference fast - full: {np.mean(m1[ok] - m2[ok]):+.4f} gray levels "
          f"(per-pixel z-test rejects {100 * np.mean(np.abs(z[ok]) > 2.576):.2f} % at 1 %)")
    print(f"  pooled variance ratio fast / full: {np.mean(v1[ok]) / np.mean(v2[ok]):.4f} "
          f"(per-pixel F-test rejects {100 * np.mean(p_var < 0.01):.2f} % at 1 %)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=240, help="full-resolution side (px)")
    parser.add_argument("--samples", type=int, default=40)
    parser.add_argument("--patterns", type=int, default=4, help="site patterns (x4 colours)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--noise", default="sigma3")
    parser.add_argument("--agreement", type=int, default=0, metavar="DRAWS",
                        help="also check per-pixel statistics of both paths over DRAWS draws")
    args = parse_args(parser, argv, samples=4, repeats=1, agreement=20)
    if args.agreement:
        agreement(args.size, args.agreement, args.noise)
    noise = preset(args.noise)
    full = make_models(args.samples, args.size)
    t = time.perf_counter()
    small = full.downscaled(120)
    t_down = time.perf_counter() - t
    W = (np.random.default_rng(1).random((8, args.patterns)) < 0.5).astype(float)
    W[0] = 1
    n_images = args.samples * args.patterns * 4
    factor = args.size // 120

    def full_path():
        rng = np.random.default_rng(2)
        img = render_noisy(full, W, noise, rng)
        return img.reshape(*img.shape[:2], 120, factor, 120, factor).mean(axis=(3, 5))

    def fast_path():
        return render_noisy(small, W, noise, np.random.default_rng(2))

    full_path(), fast_path()  # warm up
    r_full = best_rate(full_path, n_images, args.repeats)
    r_fast = best_rate(fast_path, n_images, args.repeats)
    print(f"{args.samples} samples x {args.patterns} site patterns x 4 colours = {n_images} "
          f"images of 120 x 120, noise {args.noise}, best of {args.repeats}")
    print(f"full resolution ({args.size} px, noise, then downscale): {r_full:10.0f} images/s")
    print(f"fast low-resolution path (downscaled models):      {r_fast:10.0f} images/s")
    print(f"speedup: {r_fast / r_full:.1f}x (one-off model downscale: {t_down * 1000:.0f} ms "
          f"for {args.samples} samples)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
