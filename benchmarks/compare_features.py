"""Which feature extractor for objects placed any way? Accuracy per feature x illumination x
placement on held-out poses, and the extractors' speed.

Generates two small synthetic datasets in memory (`lightstage_physics.synth`, rendered
straight at 120 px; camera noise of the variance a 240 px capture has after its 2 x 2
downscale): the same objects in canonical and in free placement. Renders every sample
under a few FIXED illuminations with fresh Sigma3 noise (`mux_trainer.rendering`):

- naive: all 32 LEDs on, one image;
- colour_all: each colour with all 8 sites, 4 images;
- s_matrix_2: the first 2 patterns of the SNR-style S-matrix code (`snr_optimal`), each
  per colour, 8 images;
- random_2: 2 seeded random site patterns per colour, 8 images;
- single_2: two opposite single sites per colour (grazing-ish light), 8 images.

For each of `--splits` random pose splits (25 % of the pose indices held out, the same for
every class; `--holdout instances`: leave one physical sample out instead) every extractor
is fit on the training stacks only, then a LinearSVC (C=1) is
trained on the training features and scored on the held-out ones. Prints mean accuracy
(and its standard error over splits) per feature x illumination x placement, and each
extractor's transform time in ms per 800 images of 120 x 120.

    .venv/bin/python benchmarks/compare_features.py [--types coin,note,green_apple,banana]
        [--samples 2] [--poses 8] [--splits 5] [--features hog_grid,pooled_hog_stats,...]
        [--holdout poses|instances]
    .venv/bin/python benchmarks/compare_features.py --quick   # 2 types, 2 features, 2 lights, canonical
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from joblib import Parallel, delayed
from sklearn.svm import LinearSVC

from lightstage_physics.noise import preset
from lightstage_physics.rig import Rig
from lightstage_physics.synth import plan, render_job
from mux_classifier.features import EXTRACTORS, extractor, features_for_split
from mux_trainer.rendering import (SearchData, add_noise, clean_led_images, clean_site_images,
                                   standard_normal)
from mux_trainer.snr_optimal import s_matrix_for_sites

from _common import parse_args

IMAGE_SIZE = 120
DOWNSCALE_NOISE = 0.25  # variance factor of a 2 x 2 area mean (240 px capture -> 120 px)


def dataset(types, samples: int, poses: int, placement: str, seed: int, n_jobs: int):
    """Relightable models (n, 4, 8, 120, 120), labels, pose indices, class names."""
    rig = Rig.paper_default(IMAGE_SIZE)
    jobs = plan(types, samples, poses, seed)
    models = Parallel(n_jobs=n_jobs, batch_size=8)(
        delayed(render_job)(job, rig, 1.0, 0.1, placement) for job in jobs)
    names = sorted({job.class_name for job in jobs})
    labels = np.array([names.index(job.class_name) for job in jobs])
    pose_index = np.array([job.instance * poses + job.pose for job in jobs])
    instance = np.array([job.instance for job in jobs])
    return np.stack(models), labels, pose_index, instance, names


def illuminations(n_sites: int, seed: int) -> dict:
    """name -> ("site", W (sites, k)) per-colour patterns, or ("led", P (32, k))."""
    rng = np.random.default_rng(seed)
    random_w = (rng.random((n_sites, 2)) < 0.5).astype(np.float32)
    random_w[0, random_w.sum(axis=0) == 0] = 1  # never all off
    single = np.zeros((n_sites, 2), np.float32)
    single[0, 0] = single[n_sites // 2, 1] = 1
    return {
        "naive": ("led", np.ones((4 * n_sites, 1), np.float32)),
        "colour_all": ("site", np.ones((n_sites, 1), np.float32)),
        "s_matrix_2": ("site", s_matrix_for_sites(n_sites)[:, :2]),
        "random_2": ("site", random_w),
        "single_2": ("site", single),
    }


def render_stacks(data: SearchData, kind: str, patterns: np.ndarray, rng) -> np.ndarray:
    clean = (clean_led_images if kind == "led" else clean_site_images)(data, patterns)
    noisy = add_noise(data, clean, standard_normal(rng, clean.shape))
    H, W = data.image_shape
    return np.ascontiguousarray(noisy.transpose(1, 0, 2)).reshape(data.n_samples, -1, H, W)


def pose_splits(pose_index: np.ndarray, n_splits: int, seed: int):
    rng = np.random.default_rng(seed)
    poses = np.unique(pose_index)
    n_test = max(1, round(0.25 * len(poses)))
    for _ in range(n_splits):
        test_poses = rng.choice(poses, n_test, replace=False)
        test = np.isin(pose_index, test_poses)
        yield np.flatnonzero(~test), np.flatnonzero(test)


def instance_splits(instance: np.ndarray):
    """Leave one physical instance (sample index, the same for every class) out."""
    for held_out in np.unique(instance):
        yield np.flatnonzero(instance != held_out), np.flatnonzero(instance == held_out)


def score(name: str, stacks, labels, train, test) -> tuple[float, float]:
    """Held-out accuracy and the extractor's transform seconds per image."""
    X_train, _, ex = features_for_split(name, stacks, train, test, image_size=IMAGE_SIZE)
    start = time.perf_counter()
    X_test = ex.transform(stacks[test])
    per_image = (time.perf_counter() - start) / (len(test) * stacks.shape[1])
    svm = LinearSVC(C=1.0, max_iter=20000, random_state=0).fit(X_train, labels[train])
    return float(np.mean(svm.predict(X_test) == labels[test])), per_image


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--types", default="coin,note,green_apple,banana")
    parser.add_argument("--samples", type=int, default=2)
    parser.add_argument("--poses", type=int, default=8)
    parser.add_argument("--splits", type=int, default=5)
    parser.add_argument("--features", default=",".join(EXTRACTORS))
    parser.add_argument("--illuminations", default="naive,colour_all,s_matrix_2,random_2,single_2")
    parser.add_argument("--placements", default="canonical,free")
    parser.add_argument("--noise", default="sigma3")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--holdout", choices=("poses", "instances"), default="poses",
                        help="poses: --splits random splits of held-out pose indices (the "
                             "paper's protocol; test objects were seen in other poses); "
                             "instances: leave one physical sample out (unseen objects)")
    args = parse_args(parser, argv, types='banana,orange', poses=4, splits=2,
                      features='hog_grid,intensity_stats', illuminations='naive,colour_all',
                      placements='canonical')
    types = tuple(t for t in args.types.split(",") if t)
    features = [f for f in args.features.split(",") if f]
    for f in features:
        extractor(f)  # unknown names fail before any rendering
    model = preset(args.noise)
    all_lights = illuminations(8, args.seed)
    lights = {k: all_lights[k] for k in args.illuminations.split(",")}
    results: dict = {}
    speed: dict = {f: [] for f in features}
    for placement in args.placements.split(","):
        start = time.perf_counter()
        models, labels, pose_index, instance, names = dataset(
            types, args.samples, args.poses, placement, args.seed, args.jobs)
        print(f"# {placement}: {len(names)} classes x {args.samples * args.poses} poses "
              f"rendered in {time.perf_counter() - start:.0f} s", flush=True)
        data = SearchData.from_models(
            models, labels, pose_index, names,
            noise_a=0.0 if model is None else model.sigma_p2 * DOWNSCALE_NOISE,
            noise_b=0.0 if model is None else model.sigma_r2 * DOWNSCALE_NOISE)
        rng = np.random.default_rng(args.seed + 1)
        for light, (kind, patterns) in lights.items():
            splits = (instance_splits(instance) if args.holdout == "instances"
                      else pose_splits(pose_index, args.splits, args.seed))
            for train, test in splits:
                stacks = render_stacks(data, kind, patterns, rng)  # fresh noise per split
                for f in features:
                    acc, per_image = score(f, stacks, labels, train, test)
                    results.setdefault((placement, light, f), []).append(acc)
                    speed[f].append(per_image)
            row = "  ".join(f"{f} {100 * np.mean(results[(placement, light, f)]):5.1f}"
                            for f in features)
            print(f"{placement:9s} {light:10s} {row}", flush=True)
    print("\n| placement | illumination | " + " | ".join(features) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in features) + " |")
    for placement in args.placements.split(","):
        for light in lights:
            cells = []
            for f in features:
                accs = np.array(results[(placement, light, f)]) * 100
                cells.append(f"{accs.mean():.1f} +- {accs.std(ddof=1) / np.sqrt(len(accs)):.1f}"
                             if len(accs) > 1 else f"{accs.mean():.1f}")
            print(f"| {placement} | {light} | " + " | ".join(cells) + " |")
    print("\n| feature | values per image | transform ms per 800 images (120 x 120) |")
    print("| --- | --- | --- |")
    for f in features:
        ex = extractor(f, image_size=IMAGE_SIZE)
        print(f"| {f} | {ex.features_per_image} | {1000 * 800 * np.median(speed[f]):.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
