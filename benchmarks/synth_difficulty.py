"""How hard is the synthetic dataset? Pose-split accuracy of HOG + linear SVM per pattern.

For a capture folder (default: generate the default synthetic set into a temp folder) this
renders every sample under a few illumination patterns at 120 x 120 (fast low-resolution
path: downscaled models + noise of the downscaled variance), adds camera noise (default
Sigma3), computes HOG (12 px cells, 10 x 10-cell block, 9 bins, L2-Hys: 900 values per
image, skimage.feature.hog), concatenates a sample's images, and reports the mean test
accuracy of a linear SVM over repeated 75 / 25 pose splits (the same pose indices for
every class), plus the held-out-instance accuracy (train on some physical samples, test on
the others; the paper's captured-imagery experiment).

    .venv/bin/python benchmarks/synth_difficulty.py [CAPTURE] [--splits 20]
    .venv/bin/python benchmarks/synth_difficulty.py --quick   # a small capture, 2 splits
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from skimage.feature import hog
from sklearn.svm import LinearSVC

from lightstage_physics.capture_format import load_capture
from lightstage_physics.noise import preset
from lightstage_physics.render import render_noisy
from lightstage_physics.rig import led_index

from _common import parse_args, small_capture


def hog_features(images: np.ndarray) -> np.ndarray:
    """(n, k, 120, 120) -> (n, k * 900). mux_classifier's batched HOG when importable
    (equal to skimage to ~1e-6, ~8x faster), else skimage.feature.hog."""
    n, k = images.shape[:2]
    try:
        from mux_classifier.hog import hog_batch
        return hog_batch(images.reshape(n * k, *images.shape[2:])).reshape(n, -1)
    except ImportError:
        pass
    feats = [hog(im, orientations=9, pixels_per_cell=(12, 12), cells_per_block=(10, 10),
                 block_norm="L2-Hys", feature_vector=True) for im in images.reshape(n * k, *images.shape[2:])]
    return np.asarray(feats, np.float32).reshape(n, -1)


def pose_split_accuracy(X, y, pose, n_splits, rng, C=1.0, object_type=None):
    """Mean and sd of test accuracy over random 75/25 pose splits, and the mean accuracy of
    the predicted object type (class label prefix) when `object_type` maps labels to types."""
    poses = np.unique(pose)
    n_test = max(1, round(0.25 * len(poses)))
    accs, type_accs = [], []
    for _ in range(n_splits):
        test_poses = rng.choice(poses, n_test, replace=False)
        test = np.isin(pose, test_poses)
        predicted = LinearSVC(C=C, max_iter=5000).fit(X[~test], y[~test]).predict(X[test])
        accs.append(np.mean(predicted == y[test]))
        if object_type is not None:
            type_accs.append(np.mean(object_type[predicted] == object_type[y[test]]))
    type_acc = float(np.mean(type_accs)) if type_accs else float("nan")
    return float(np.mean(accs)), float(np.std(accs)), type_acc


def instance_split_accuracy(X, y, instance, C=1.0):
    """Leave-one-instance-out over the physical samples of every class."""
    accs = []
    for held in np.unique(instance):
        test = instance == held
        clf = LinearSVC(C=C, max_iter=5000).fit(X[~test], y[~test])
        accs.append(np.mean(clf.predict(X[test]) == y[test]))
    return float(np.mean(accs))


def patterns():
    """name -> (mode, matrix). Site patterns give 4 images (R,G,B,NIR); LED patterns 1 each."""
    out = {"naive: all 32 LEDs, one image": ("led", np.ones((32, 1)))}
    out["all sites, per colour (4 images)"] = ("site", np.ones((8, 1)))
    for s in range(8):
        w = np.zeros((8, 1))
        w[s] = 1
        out[f"site {s} alone, per colour (4 images)"] = ("site", w)
    out["lower sites 0-3, per colour"] = ("site", np.r_[np.ones(4), np.zeros(4)][:, None])
    out["upper sites 4-7, per colour"] = ("site", np.r_[np.zeros(4), np.ones(4)][:, None])
    for s in (0, 2):
        P = np.zeros((32, 1))
        P[led_index(s, "nir")] = 1
        out[f"site {s} NIR only, one image"] = ("led", P)
    P = np.zeros((32, 1))
    P[[led_index(s, "nir") for s in range(8)]] = 1
    out["all sites NIR only, one image"] = ("led", P)
    out["sites 0 & 2 alone, per colour (8 images)"] = ("site", np.eye(8)[:, [0, 2]])
    out["sites 0,1,2,3 alone, per colour (16 images)"] = ("site", np.eye(8)[:, :4])
    out["[all sites | site 4], per colour (8 images)"] = (
        "site", np.c_[np.ones(8), np.eye(8)[:, 4]])
    out["[all | site 4 | site 1 | upper 4-7], per colour (16)"] = (
        "site", np.c_[np.ones(8), np.eye(8)[:, 4], np.eye(8)[:, 1], np.r_[np.zeros(4), np.ones(4)]])
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("capture", nargs="?", help="capture folder (default: generate one)")
    parser.add_argument("--noise", default="sigma3")
    parser.add_argument("--splits", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--C", type=float, default=1.0)
    parser.add_argument("--only", default="", help="comma-separated substrings of pattern names")
    args = parse_args(parser, argv, splits=2)
    if args.capture is None and args.quick:
        args.capture = str(small_capture())
    if args.capture is None:
        from lightstage_physics.synth import generate
        tmp = tempfile.mkdtemp(prefix="synth_")
        t0 = time.perf_counter()
        generate(tmp)
        print(f"generated default dataset in {time.perf_counter() - t0:.1f} s -> {tmp}")
        args.capture = tmp
    t0 = time.perf_counter()
    ms = load_capture(Path(args.capture), downscale_to=120)
    print(f"loaded {len(ms)} samples, {ms.n_classes} classes, 120 x 120 "
          f"(noise_scale {ms.noise_scale:.3f}) in {time.perf_counter() - t0:.1f} s")
    noise = preset(args.noise)
    print(f"noise {args.noise}; {args.splits} pose splits 75/25; LinearSVC(C={args.C})")
    types = np.array([c.split("-", 1)[0] for c in ms.class_names])
    print(f"{'pattern':<52} {'pose-split acc %':>17} {'type %':>7} {'held-out instance %':>20}")
    rng = np.random.default_rng(args.seed)
    wanted = [w.strip() for w in args.only.split(",") if w.strip()]
    for name, (mode, matrix) in patterns().items():
        if wanted and not any(w in name for w in wanted):
            continue
        images = render_noisy(ms, matrix, noise, rng, mode=mode)
        X = hog_features(images)
        mean, std, type_acc = pose_split_accuracy(X, ms.labels, ms.pose_index, args.splits,
                                                  np.random.default_rng(args.seed), args.C,
                                                  types)
        inst = instance_split_accuracy(X, ms.labels, ms.instance, args.C)
        print(f"{name:<52} {100 * mean:>10.1f} +- {100 * std:4.1f} {100 * type_acc:>7.1f} "
              f"{100 * inst:>19.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
