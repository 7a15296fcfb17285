#!/usr/bin/env python3
"""HOG speed: skimage.feature.hog per image vs mux_classifier.hog.hog_batch, side by side.

Both extract the paper's descriptor (120 x 120, 12 px cells, 10 x 10-cell blocks, 9 bins,
L2-Hys: 900 values) from the same random float32 images in one run, and the batched
result is checked against skimage before timing. The two are timed alternately; prints
the best ms per image of each, the median of the per-run ratios, and hog_batch's time
for several internal batch sizes.

    .venv/bin/python benchmarks/bench_hog.py [--images 512] [--repeats 9]
(with src/mux_classifier on PYTHONPATH if the package is not installed)
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "src", "mux_classifier"))

from mux_classifier.hog import HogConfig, hog_batch, hog_reference  # noqa: E402


def best_of(fn, repeats: int) -> float:
    """Smallest wall time of `repeats` runs (the least disturbed by other processes)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=512, help="images timed for hog_batch")
    parser.add_argument("--reference-images", type=int, default=64,
                        help="images timed for skimage (slow)")
    parser.add_argument("--repeats", type=int, default=9, help="runs per figure")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    images = rng.uniform(0, 1023, (args.images, 120, 120)).astype(np.float32)
    config = HogConfig()

    ref_imgs = images[:args.reference_images]
    reference = np.stack([hog_reference(img, config) for img in ref_imgs])
    batched = hog_batch(ref_imgs, config)
    max_diff = float(np.abs(batched - reference).max())
    if max_diff > 1e-6:
        print(f"ERROR: hog_batch differs from skimage by {max_diff:.3g}", file=sys.stderr)
        return 1

    # Interleave the two so that load from other processes hits both alike; each repeat
    # gives one ratio, the median ratio is reported next to the best times.
    ref_times, fast_times = [], []
    for _ in range(args.repeats):
        ref_times.append(best_of(lambda: [hog_reference(img, config) for img in ref_imgs], 1)
                         / len(ref_imgs))
        fast_times.append(best_of(lambda: hog_batch(images, config), 1) / len(images))
    ratios = np.array(ref_times) / np.array(fast_times)
    ms_ref = 1e3 * min(ref_times)
    ms_fast = 1e3 * min(fast_times)

    print(f"HOG 120x120 -> {config.n_features} values; numpy {np.__version__}; "
          f"{args.repeats} interleaved runs; cpus {os.cpu_count()}; "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"max |hog_batch - skimage| = {max_diff:.2e} over {len(ref_imgs)} images")
    print(f"{'method':<34}{'ms/image (best)':>16}")
    print(f"{'skimage.feature.hog (per image)':<34}{ms_ref:>16.3f}")
    print(f"{'hog_batch (batch_size=' + str(config.batch_size) + ')':<34}{ms_fast:>16.3f}")
    print(f"speed-up: median {np.median(ratios):.1f}x over runs (min {ratios.min():.1f}x, "
          f"max {ratios.max():.1f}x); ratio of best times {ms_ref / ms_fast:.1f}x")
    print("hog_batch by internal batch size:")
    for batch_size in (1, 4, 8, 16, 32, 64):
        cfg = HogConfig(batch_size=batch_size)
        t = best_of(lambda: hog_batch(images, cfg), args.repeats)
        print(f"  batch_size={batch_size:<3} {1e3 * t / len(images):8.3f} ms/image")
    return 0


if __name__ == "__main__":
    sys.exit(main())
