#!/usr/bin/env python3
"""HOG speed: skimage.feature.hog per image, the numpy reference and the compiled kernel.

All three extract the paper's descriptor (120 x 120, 12 px cells, 10 x 10-cell blocks, 9
bins, L2-Hys: 900 values) from the same random float32 images in one run; the results are
checked against skimage before timing. They are timed alternately; prints the best ms per
image of each, the median of the per-run ratios, the numpy reference's time for several
internal batch sizes, and what the compiled kernel's first call costs in a new process:
a compile (no cache) and a cache load (measured in subprocesses with a fresh
NUMBA_CACHE_DIR).

    .venv/bin/python benchmarks/bench_hog.py [--images 512] [--repeats 9]
    .venv/bin/python benchmarks/bench_hog.py --quick   # 16 images, 1 run
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from mux_classifier.hog import HogConfig, hog_batch, hog_batch_numpy, hog_reference

from _common import parse_args

FIRST_CALL = """
import time, numpy as np
t0 = time.perf_counter()
from mux_classifier.hog import hog_batch
hog_batch(np.zeros((1, 120, 120), np.float32))
print(time.perf_counter() - t0)
"""


def first_call_seconds() -> tuple[float, float]:
    """(compile, cache load): seconds of a new process's import + first hog_batch call."""
    import subprocess
    import tempfile
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        runs = [float(subprocess.run([sys.executable, "-c", FIRST_CALL], env=env, check=True,
                                     capture_output=True, text=True).stdout) for _ in range(2)]
    return runs[0], runs[1]


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
    args = parse_args(parser, argv, images=16, reference_images=4, repeats=1)

    rng = np.random.default_rng(args.seed)
    images = rng.uniform(0, 1023, (args.images, 120, 120)).astype(np.float32)
    config = HogConfig()

    ref_imgs = images[:args.reference_images]
    reference = np.stack([hog_reference(img, config) for img in ref_imgs])
    for name, fn in (("hog_batch", hog_batch), ("hog_batch_numpy", hog_batch_numpy)):
        max_diff = float(np.abs(fn(ref_imgs, config) - reference).max())
        if max_diff > 1e-6:
            print(f"ERROR: {name} differs from skimage by {max_diff:.3g}", file=sys.stderr)
            return 1
    kernel_vs_numpy = float(np.abs(hog_batch(images, config) - hog_batch_numpy(images, config)).max())

    # Interleave the three so that load from other processes hits them alike; each repeat
    # gives one ratio per method, the median ratio is reported next to the best times.
    methods = {
        "skimage.feature.hog (per image)": (lambda: [hog_reference(img, config) for img in ref_imgs],
                                            len(ref_imgs)),
        f"hog_batch_numpy (batch_size={config.batch_size})": (lambda: hog_batch_numpy(images, config),
                                                             len(images)),
        "hog_batch (compiled kernel)": (lambda: hog_batch(images, config), len(images)),
    }
    times = {name: [] for name in methods}
    for _ in range(args.repeats):
        for name, (fn, count) in methods.items():
            times[name].append(best_of(fn, 1) / count)
    sk = np.array(times["skimage.feature.hog (per image)"])

    print(f"HOG 120x120 -> {config.n_features} values; numpy {np.__version__}; "
          f"{args.repeats} interleaved runs; cpus {os.cpu_count()}; "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"max |hog_batch - skimage| = {float(np.abs(hog_batch(ref_imgs) - reference).max()):.2e} "
          f"over {len(ref_imgs)} images; max |hog_batch - hog_batch_numpy| = "
          f"{kernel_vs_numpy:.2e} over {len(images)}")
    print(f"{'method':<36}{'ms/image (best)':>16}{'speed-up vs skimage (median)':>31}")
    for name, t in times.items():
        ratio = np.median(sk / np.array(t))
        print(f"{name:<36}{1e3 * min(t):>16.3f}{ratio:>30.1f}x")
    print("hog_batch_numpy by internal batch size:")
    for batch_size in (1, 4, 8, 16, 32, 64):
        cfg = HogConfig(batch_size=batch_size)
        t = best_of(lambda: hog_batch_numpy(images, cfg), args.repeats)
        print(f"  batch_size={batch_size:<3} {1e3 * t / len(images):8.3f} ms/image")
    compile_s, load_s = first_call_seconds()
    print(f"compiled kernel, first call in a new process (import included): {compile_s:.2f} s "
          f"without a cache (compile), {load_s:.2f} s with it (cache load)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
