#!/usr/bin/env python3
"""intensity_stats speed: the compiled kernel, its exact numpy reference and the HOG grid.

All three run on the same float32 120 x 120 images (a bright textured object on a dark
noisy floor, clipped to 10-bit levels), timed alternately in one run so that load from
other processes hits them alike. Prints ms per 1000 images (best of the runs) for
``intensity_stats_images``, ``intensity_stats_images_numpy`` and ``hog_batch``, for small
and large objects, and the kernel's largest deviation from the reference (in histogram bins).

    .venv/bin/python benchmarks/bench_intensity_stats.py [--images 512] [--repeats 9]
    .venv/bin/python benchmarks/bench_intensity_stats.py --quick   # 16 images, 1 run
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from mux_classifier.hog import hog_batch
from mux_classifier.intensity_stats import (N_BINS, intensity_stats_images,
                                            intensity_stats_images_numpy)

from _common import parse_args


def objects(n: int, extent: tuple[int, int], seed: int) -> np.ndarray:
    """Textured rectangles (sides drawn from extent, px) on a dark noisy floor."""
    rng = np.random.default_rng(seed)
    images = rng.normal(40, 4, (n, 120, 120)).astype(np.float32)
    for i in range(n):
        h, w = rng.integers(*extent, 2)
        r0, c0 = rng.integers(2, 118 - max(h, w), 2)
        images[i, r0:r0 + h, c0:c0 + w] += 200 + 300 * rng.random() + rng.normal(0, 30, (h, w))
    return np.clip(images, 0, 1023)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=512)
    parser.add_argument("--reference-images", type=int, default=64,
                        help="images timed for the numpy reference (slow)")
    parser.add_argument("--repeats", type=int, default=9, help="interleaved runs per figure")
    parser.add_argument("--seed", type=int, default=0)
    args = parse_args(parser, argv, images=16, reference_images=4, repeats=1)

    print(f"120x120 float32 images; numpy {np.__version__}; {args.repeats} interleaved runs; "
          f"cpus {os.cpu_count()}; load average {os.getloadavg()[0]:.2f}")
    print(f"{'objects':<34}{'method':<32}{'ms / 1000 images':>17}")
    for label, extent in (("small (15-50 px sides, ~7 %)", (15, 50)),
                          ("large (60-90 px sides, ~40 %)", (60, 90))):
        images = objects(args.images, extent, args.seed)
        ref_imgs = images[:args.reference_images]
        fast, exact = intensity_stats_images(ref_imgs), intensity_stats_images_numpy(ref_imgs)
        level_bin = (ref_imgs.max(axis=(1, 2)) - ref_imgs.min(axis=(1, 2))) / N_BINS
        worst = float((np.abs(fast[:, :5] - exact[:, :5]) / level_bin[:, None]).max())
        hog_batch(images[:2])  # compiled (or loaded from the cache) before timing
        methods = {
            "intensity_stats_images": (lambda: intensity_stats_images(images), len(images)),
            "intensity_stats_images_numpy": (lambda: intensity_stats_images_numpy(ref_imgs),
                                             len(ref_imgs)),
            "hog_batch (HOG grid)": (lambda: hog_batch(images), len(images)),
        }
        times = {name: [] for name in methods}
        for _ in range(args.repeats):
            for name, (fn, count) in methods.items():
                t0 = time.perf_counter()
                fn()
                times[name].append((time.perf_counter() - t0) / count)
        for name, t in times.items():
            print(f"{label:<34}{name:<32}{1e6 * min(t):>17.1f}")
        ratio = np.median(np.array(times["intensity_stats_images"])
                          / np.array(times["hog_batch (HOG grid)"]))
        print(f"{'':<34}kernel / HOG (median of runs) {ratio:.2f}; largest level-quantile "
              f"deviation from the reference {worst:.2f} bins")
    return 0


if __name__ == "__main__":
    sys.exit(main())
