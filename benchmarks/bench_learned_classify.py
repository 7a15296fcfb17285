#!/usr/bin/env python3
"""Classify compute per sample for trained artifacts: what the classifier node times as
``compute_ms`` (`inference.classify_frames`: mono16 -> gray levels, the area downscale,
the artifact's estimator for its k images), on the same frames for every artifact.

Each artifact classifies ``--samples`` stacks of its own image count (mono16 frames of a
bright textured object on a dark noisy floor, ``--frame-px`` square), one sample per call
as the node does, the artifacts alternating so that load from other processes hits them
alike. Prints the median and the 90th percentile ms per sample.

    .venv/bin/python benchmarks/bench_learned_classify.py out/demo/learned_sigma3.npz \\
        out/demo/greedy_sigma3.npz [--samples 200] [--frame-px 120]
    .venv/bin/python benchmarks/bench_learned_classify.py --quick   # 20 samples

Without artifacts it first trains a learned and a greedy one (4 images, 20 inner splits) on
a small synthetic capture, and times those.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from mux_classifier.artifact import TrainedArtifact
from mux_classifier.inference import classify_frames

from _common import parse_args, small_capture


def frames(k: int, size: int, rng) -> list[np.ndarray]:
    """k mono16 frames (10 significant bits, shifted left by 6 as the camera sends them)."""
    images = rng.normal(40, 4, (k, size, size))
    h = size // 3
    images[:, h:2 * h, h:2 * h] += 300 + rng.normal(0, 30, (k, h, h))
    return list((np.clip(images, 0, 1023).astype(np.uint16) << 6))


def small_artifacts() -> list[str]:
    """A learned and a greedy artifact (4 images, 20 inner splits) trained on the small
    capture, in a temporary folder."""
    import tempfile
    from mux_trainer.training import train_from_capture
    folder = Path(tempfile.mkdtemp(prefix="bench-learned-classify-"))
    paths = []
    for method in ("learned", "greedy"):
        paths.append(str(folder / f"{method}.npz"))
        train_from_capture(small_capture(), paths[-1], method=method, max_images=4, repeats=20)
    return paths


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("artifacts", nargs="*", help="artifact files (default: train two, see above)")
    p.add_argument("--samples", type=int, default=200)
    p.add_argument("--frame-px", type=int, default=120)
    args = parse_args(p, argv, samples=20)
    if not args.artifacts:
        args.artifacts = small_artifacts()
    rng = np.random.default_rng(0)
    arts = [TrainedArtifact.load(path) for path in args.artifacts]
    times = [[] for _ in arts]
    for _ in range(args.samples):
        for art, spent in zip(arts, times):
            stack = frames(art.n_images[-1], args.frame_px, rng)
            t0 = time.perf_counter()
            classify_frames(art, stack)
            spent.append((time.perf_counter() - t0) * 1e3)
    print(f"load average {os.getloadavg()[0]:.1f}; {args.samples} samples, one per call, "
          f"frames {args.frame_px} px")
    for path, art, spent in zip(args.artifacts, arts, times):
        print(f"  {os.path.basename(path):<24} {art.mode:<10} {art.n_images[-1]:>3} images  "
              f"median {np.median(spent):6.2f} ms  p90 {np.percentile(spent, 90):6.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
