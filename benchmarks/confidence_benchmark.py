"""Calibrated probabilities and the anytime rule on physical samples never seen in training.

A capture of `lightstage synth` (default: the demo's five fruit, real and fake, --samples
physical samples per class, --poses poses, rendered at --size px and loaded at 120 px) is
split by physical sample: fold f holds out sample number f of every class with all its poses.
Each method (greedy, SNR-optimal, naive: `lightstage train`'s estimators with --repeats
inner splits held out by physical sample) is trained on the rest, calibrated as `lightstage
train` calibrates it (`mux_trainer.calibration.calibrate_pattern_model`) and scored on fresh
Sigma3 renders of the held-out samples (`calibration.evaluate_anytime`, --n-renders noise
draws): the accuracy at its full count (its kept column count, the budget), the anytime
rule's accuracy and mean exposures, the expected calibration error of both, and the share
and accuracy of the answers that reach the target (accepted: the rest are unsure).

Prints one row per method and fold and the fold means; --json writes every figure.

    .venv/bin/python benchmarks/confidence_benchmark.py                 # quick: 2 folds, 60 px
    .venv/bin/python benchmarks/confidence_benchmark.py --quick         # make bench: 2 fruit, tiny
    .venv/bin/python benchmarks/confidence_benchmark.py --size 240 --folds 4 --repeats 100
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import parse_args as parse_with_quick

METHODS = ('greedy', 'snr_optimal', 'naive')
OTHER_METHODS = ('learned',)  # by --methods: LED levels learned, --learned-exposures images


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--capture', help='an existing capture folder (default: synthesise one)')
    p.add_argument('--size', type=int, default=120, help='synthesised image size in px (120)')
    p.add_argument('--samples', type=int, default=4, help='physical samples per class (4)')
    p.add_argument('--poses', type=int, default=3, help='poses per sample (3)')
    p.add_argument('--types', default='green_apple,red_apple,grape,banana,orange',
                   help='object types (default: the five fruit)')
    p.add_argument('--folds', type=int, default=2,
                   help='folds; fold f holds out sample number f of every class (2)')
    p.add_argument('--repeats', type=int, default=40, help='inner splits per candidate (40)')
    p.add_argument('--max-columns', type=int, default=4,
                   help='pattern columns of greedy and SNR-optimal (4, 16 exposures)')
    p.add_argument('--n-renders', type=int, default=4, help='noise draws of the test renders (4)')
    p.add_argument('--methods', default=','.join(METHODS), help='methods, of greedy,snr_optimal,naive,learned '
                   '(default: greedy,snr_optimal,naive)')
    p.add_argument('--learned-exposures', type=int, default=8,
                   help='exposures of the learned method (8, as the demo\'s)')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--jobs', type=int, default=2)
    p.add_argument('--json', help='write every figure to this file')
    return parse_with_quick(p, argv, types='banana,orange', samples=2, poses=2, repeats=10,
                            max_columns=2, n_renders=1, jobs=1)


def build(method: str, args):
    from mux_trainer.baselines import NaiveClassifier, SnrOptimalClassifier
    from mux_trainer.greedy import GreedyPatternSelector
    from mux_trainer.search_params import Execution, SplitScoring
    common = dict(scoring=SplitScoring(n_repeats=args.repeats), seed=args.seed,
                  execution=Execution(n_jobs=args.jobs))
    if method == 'greedy':
        return GreedyPatternSelector(mode='per_colour', max_patterns=args.max_columns, **common)
    if method == 'snr_optimal':
        return SnrOptimalClassifier(n_images=args.max_columns, **common)
    if method == 'learned':
        from mux_trainer.learned_method import build_learned
        return build_learned(args.learned_exposures, seed=args.seed, n_repeats=args.repeats)
    return NaiveClassifier(**common)


def main(argv=None) -> int:
    args = parse_args(argv)
    from lightstage_physics import synth
    from lightstage_physics.capture_format import load_capture
    from mux_trainer.calibration import (calibrate_learned_model, calibrate_pattern_model,
                                         calibration_error_floor, evaluate_learned_answers,
                                         evaluate_anytime, pooled_calibration_error)
    from mux_trainer.data import search_data

    methods = [m for m in args.methods.split(',') if m]
    with tempfile.TemporaryDirectory() as tmp:
        capture = Path(args.capture) if args.capture else Path(tmp) / 'capture'
        if not args.capture:
            t0 = time.perf_counter()
            synth.generate(capture, image_size=args.size, n_samples_per_class=args.samples,
                           n_poses=args.poses, object_types=tuple(args.types.split(',')),
                           seed=args.seed, n_jobs=args.jobs)
            print(f'capture: {args.types}, {args.samples} samples x {args.poses} poses at '
                  f'{args.size} px ({time.perf_counter() - t0:.0f} s)', flush=True)
        modelset = load_capture(capture, downscale_to=120)
        data = search_data(modelset, 'sigma3')
        instance = np.asarray(modelset.instance)
    rows = []
    print(f'{"method":<12} {"fold":>4} {"full %":>7} {"at":>4} {"anytime %":>10} '
          f'{"mean exp":>9} {"share":>6} {"ECE full":>9} {"ECE any":>8} {"accepted":>14}')
    for fold in range(args.folds):
        test = instance == fold
        train_data, test_data = data.subset(np.flatnonzero(~test)), data.subset(np.flatnonzero(test))
        for method in methods:
            t0 = time.perf_counter()
            model = build(method, args).fit(train_data)
            learned = method == 'learned'
            confidence = (calibrate_learned_model if learned else calibrate_pattern_model)(model)
            seconds = time.perf_counter() - t0
            r = (evaluate_learned_answers if learned else evaluate_anytime)(
                model, confidence, test_data, args.n_renders, args.seed)
            r.update(method=method, fold=fold, train_seconds=seconds,
                     trained_estimate=confidence.estimate)
            rows.append(r)
            accepted = (f'{100 * r["accepted_share"]:.0f} % at '
                        f'{100 * r["accepted_accuracy"]:.1f}' if r['accepted_accuracy'] is not None
                        else '-')
            print(f'{method:<12} {fold:>4} {100 * r["full_accuracy"]:>7.1f} '
                  f'{r["budget_images"]:>4} {100 * r["anytime_accuracy"]:>10.1f} '
                  f'{r["anytime_mean_images"]:>9.1f} '
                  f'{r["anytime_mean_images"] / r["budget_images"]:>6.2f} '
                  f'{r["full_calibration_error"]:>9.3f} {r["anytime_calibration_error"]:>8.3f} '
                  f'{accepted:>14}', flush=True)
    print('\nmeans over the folds (held-out physical samples, Sigma3); calibration error of '
          'all folds\' answers together, beside what a perfectly calibrated classifier would '
          'measure on as many answers (its floor):')
    for method in methods:
        mine = [r for r in rows if r['method'] == method]
        mean = {k: float(np.mean([r[k] for r in mine])) for k in (
            'full_accuracy', 'anytime_accuracy', 'anytime_mean_images', 'budget_images',
            'full_calibration_error', 'anytime_calibration_error')}
        print(f'{method:<12} full {100 * mean["full_accuracy"]:.1f} % at '
              f'{mean["budget_images"]:.1f} exposures; anytime {100 * mean["anytime_accuracy"]:.1f} % '
              f'at {mean["anytime_mean_images"]:.1f} '
              f'({100 * mean["anytime_mean_images"] / mean["budget_images"]:.0f} % of the '
              f'exposures); calibration error {mean["full_calibration_error"]:.3f} full, '
              f'{mean["anytime_calibration_error"]:.3f} anytime; all folds together '
              f'{pooled_calibration_error([r["reliability"]["full"] for r in mine]):.3f} full, '
              f'{pooled_calibration_error([r["reliability"]["anytime"] for r in mine]):.3f} '
              f'anytime (floor about '
              f'{calibration_error_floor([r["reliability"]["full"] for r in mine]):.3f})')
    if args.json:
        Path(args.json).write_text(json.dumps({'args': vars(args), 'rows': rows}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
