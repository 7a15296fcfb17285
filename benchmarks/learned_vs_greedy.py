"""Learned illumination (graded and on/off) against greedy and SNR-optimal, on one held-out
split, at 4 and 8 exposures.

For each capture: the SearchData at 120 px with Sigma3 noise and `--features` (default
intensity_stats, the pose-robust statistics the learned model is built on), the held-out
split of `holdout.holdout_split` (25 % of the pose indices, or of the physical samples with
`--holdout-by instances`), then on the training part:
- greedy per colour, 2 columns (4 and 8 exposures; `GreedyPatternSelector`, n_repeats as
  given, default the method's 400), evaluated by `holdout.method_summary`;
- SNR-optimal, its first 2 columns, likewise;
- learned (graded; on/off as learned_binary), trained separately for 4 and for 8 images
  (one exposure each), with the estimator's starts and descents unless --learned-starts /
  --fine-tune say otherwise; its greedy start is this run's greedy columns when greedy ran
  (the same search the estimator would run: its seconds are then not in learned's), and
  learned_starts: the same without fine-tuning (the best start by the inner splits),
  the control for what the gradient steps add; evaluated by
  `learned.evaluate_learned_heldout`: the same test-noise stream (`holdout.test_images`)
  and the same n_renders.
`--inner-groups` is every method's `SplitScoring.inner_groups` (greedy's, SNR-optimal's, the
learned loss's folds and its candidate scoring): 'poses', 'instances' (whole physical
samples) or 'auto' (instances where the training part has two or more of every class).
Prints held-out accuracy, the inner estimate (the method's own split accuracy at that
exposure count) and training seconds per method and exposure count, and writes the figures
as JSON with --json.

    .venv/bin/python benchmarks/learned_vs_greedy.py DIR [DIR ...] [--seed 0]
    .venv/bin/python benchmarks/learned_vs_greedy.py --quick   # a small capture, 4 exposures, 20 splits
Without a capture: the default synthetic dataset (benchmarks/_common.py, `default_capture`).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from lightstage_physics.capture_format import load_capture
from mux_trainer.baselines import SnrOptimalClassifier
from mux_trainer.data import search_data
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.holdout import holdout_split, method_summary, test_images
from lightstage_physics.rig import site_to_led_patterns
from mux_trainer.learned_schedule import DEFAULT_STEPS
from mux_trainer.learned import (Descent, Head, LearnedIlluminationClassifier, Starts,
                                 evaluate_learned_heldout)
from mux_trainer.search_params import Execution, SplitScoring

from _common import capture_or_default, parse_args


def classify_ms(model, test, seed, repeats=20) -> float:
    """Compute of one classification with the numpy model (features + head), one sample."""
    images = test_images(test, 'joint', model.patterns_, 0, seed)[:, :1]
    k, n, p = images.shape
    side = int(round(np.sqrt(p)))
    stack = images.transpose(1, 0, 2).reshape(1, k, side, p // side)
    model.model_.predict(stack)
    t0 = time.perf_counter()
    for _ in range(repeats):
        model.model_.predict(stack)
    return (time.perf_counter() - t0) * 1e3 / repeats


def split_capture(path, holdout_by: str, seed: int, features: str = 'intensity_stats'):
    """The capture at 120 px with Sigma3 noise, split by `holdout.holdout_split` (25 % of the
    pose indices, or of the physical samples with holdout_by 'instances'): (train, test,
    the training samples' physical sample numbers)."""
    ms = load_capture(path, downscale_to=120)
    data = search_data(ms, 'sigma3', features=features)
    instance = np.asarray(ms.instance)
    tr, te = holdout_split(data, 0.25, seed, instance if holdout_by == 'instances' else None)
    return data.subset(tr), data.subset(te), instance[tr]


def run_capture(path, args) -> dict:
    train, test, _ = split_capture(path, args.holdout_by, args.seed, args.features)
    inner_groups = getattr(args, 'inner_groups', 'poses')
    print(f'{path}: {train.n_samples} training, {test.n_samples} held-out samples, '
          f'{len(train.class_names)} classes, held out by {args.holdout_by}, inner splits '
          f'{inner_groups}', flush=True)
    out = {}
    common = dict(seed=args.seed, scoring=SplitScoring(n_repeats=args.n_repeats,
                                                       inner_groups=inner_groups))
    for name, make in (('greedy', lambda: GreedyPatternSelector(mode='per_colour', n_patterns=2,
                                                                 **common)),
                       ('snr_optimal', lambda: SnrOptimalClassifier(n_images=2, **common))):
        if name not in args.methods:
            continue
        reused = getattr(args, 'reused', {}).get(name)
        # greedy's columns are needed (not only its figures) when they are learned's start
        columns_needed = name == 'greedy' and 'greedy' in args.learned_starts and any(
            m.startswith('learned') for m in args.methods)
        if reused is not None and not columns_needed:
            out[name] = dict(reused, reused=True)
            print(f'  {name}: 4 exp {reused["4"]:.3f}, 8 exp {reused["8"]:.3f} (from --reuse)',
                  flush=True)
            continue
        t0 = time.perf_counter()
        model = make().fit(train)
        seconds = time.perf_counter() - t0
        res = method_summary(model, test, args.n_renders, args.seed, train_seconds=seconds)
        out[name] = {'4': res['accuracy_by_images']['1'], '8': res['accuracy_by_images']['2'],
                     'estimate_4': float(model.accuracy_by_images_[1]),
                     'estimate_8': float(model.accuracy_by_images_[2]),
                     'inner_splits': model.evaluator_.inner_, 'train_seconds': seconds}
        if name == 'greedy':
            out['_greedy_columns'] = model.patterns_
        print(f'  {name}: 4 exp {out[name]["4"]:.3f} (inner {out[name]["estimate_4"]:.3f}), '
              f'8 exp {out[name]["8"]:.3f} (inner {out[name]["estimate_8"]:.3f}) '
              f'({seconds:.0f} s)', flush=True)
    greedy_columns = out.pop('_greedy_columns', None)
    variants = (('learned', False, args.fine_tune), ('learned_binary', True, args.fine_tune),
                ('learned_starts', False, 'none'))
    for name, binary, fine_tune in variants:
        if name not in args.methods:
            continue
        out[name] = {'train_seconds': 0.0}
        for k in args.exposures:
            starts, builtin = {}, list(args.learned_starts)
            if 'greedy' in builtin and greedy_columns is not None and k % 4 == 0:
                builtin.remove('greedy')   # the same columns, not searched twice
                starts['greedy'] = site_to_led_patterns(greedy_columns[:, :k // 4],
                                                        train.n_channels)
            model = LearnedIlluminationClassifier(
                n_images=k, binary=binary, seed=args.seed,
                descent=Descent(max_steps=args.steps, lr=args.lr_patterns, fine_tune=fine_tune,
                                ridge=args.ridge),
                scoring=SplitScoring(n_repeats=args.n_repeats, classifier=args.split_classifier,
                                     inner_groups=inner_groups),
                ratio_stats=args.ratio_stats, inner_draws=args.inner_draws,
                head=Head(kind=args.head, renders=args.head_renders),
                starts=Starts(names=tuple(builtin), patterns=starts),
                execution=Execution(progress=args.progress)).fit(train)
            acc = evaluate_learned_heldout(model, test, args.n_renders, args.seed)['accuracy']
            out[name][str(k)] = acc
            out[name][f'train_seconds_{k}'] = model.train_seconds_
            out[name][f'best_step_{k}'] = model.best_step_
            out[name][f'chosen_{k}'] = model.chosen_
            out[name][f'inner_{k}'] = model.candidate_scores_
            out[name][f'estimate_{k}'] = float(model.accuracy_by_images_[k])
            out[name]['inner_splits'] = model.inner_estimate_
            out[name][f'patterns_{k}'] = np.round(model.patterns_, 3).tolist()
            print(f'  {name}: {k} exp {acc:.3f} ({model.train_seconds_:.0f} s, chose '
                  f'{model.chosen_}; inner ' + ', '.join(
                      f'{c} {v:.3f}' for c, v in model.candidate_scores_.items()) + ')',
                  flush=True)
        if k == 8:
            out[name]['classify_ms_8'] = classify_ms(model, test, args.seed)
            print(f'  {name}: classify {out[name]["classify_ms_8"]:.1f} ms per sample '
                  '(numpy model, 8 images at 120 px, one sample at a time)', flush=True)
    return out


def add_method_arguments(p, default_methods='greedy,snr_optimal,learned,learned_starts'):
    """The options of `run_capture` (shared with learned_strength_sweep.py)."""
    p.add_argument('--features', default='intensity_stats')
    p.add_argument('--holdout-by', default='poses', choices=('poses', 'instances'))
    p.add_argument('--inner-groups', default='poses', choices=('auto', 'poses', 'instances'),
                   help="what every method's inner splits hold out on the training part: pose "
                        "numbers, physical samples, or auto (the product's default: physical "
                        "samples where the training part has two or more of every class)")
    p.add_argument('--n-repeats', type=int, default=400, help="greedy's / SNR's inner splits")
    p.add_argument('--n-renders', type=int, default=4)
    p.add_argument('--steps', type=int, default=DEFAULT_STEPS, help='learned: gradient steps')
    p.add_argument('--lr-patterns', type=float, default=0.2,
                   help='learned: Adam step on the LED logits')
    defaults = LearnedIlluminationClassifier()
    p.add_argument('--ridge', type=float, default=defaults.descent.ridge,
                   help="learned: the descent's fold classifiers' ridge")
    p.add_argument('--split-classifier', default=defaults.split_classifier,
                   choices=('ridge', 'squared_hinge', 'linear_svm'),
                   help="learned: the inner splits' classifier that scores starts and snapshots")
    p.add_argument('--ratio-stats', action=argparse.BooleanOptionalAction,
                   default=defaults.ratio_stats,
                   help="learned: classify with the images' cross-image relief statistics too")
    p.add_argument('--inner-draws', type=int, default=defaults.inner_draws,
                   help="learned: independent sets of inner splits (each its own noise draw) "
                        "whose mean scores a candidate")
    p.add_argument('--head-renders', type=int, default=defaults.head.renders,
                   help="learned: noise draws of the training samples the final SVM is fitted on")
    p.add_argument('--head', default=defaults.head.kind, choices=('by_type', 'flat'),
                   help="learned: the final head, gated by object type or one flat linear SVM")
    p.add_argument('--fine-tune', default=','.join(defaults.descent.fine_tune), type=lambda v: v.split(','),
                   help="learned: 'best', 'all', 'none' or the starts the steps run from")
    p.add_argument('--learned-starts', default=','.join(defaults.starts.names),
                   help="learned: start patterns ('greedy': this run's greedy columns if it ran)")
    p.add_argument('--exposures', default='4,8', type=lambda v: [int(x) for x in v.split(',')],
                   help='learned: the exposure counts to train a model for (one model each)')
    p.add_argument('--progress', action='store_true')
    p.add_argument('--reuse', help="a JSON this script wrote: its greedy and SNR-optimal figures "
                   "for the same capture and seed are taken, not recomputed (the searches are "
                   "deterministic; the options must be the same)")
    p.add_argument('--methods', default=default_methods,
                   help='among greedy, snr_optimal, learned, learned_binary, learned_starts '
                        '(learned without fine-tuning: the best start by the inner splits)')


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('captures', nargs='*', help='capture folders (default: the synthetic dataset)')
    p.add_argument('--seed', type=int, default=0)
    add_method_arguments(p)
    p.add_argument('--json', help='write the figures here')
    args = parse_args(p, argv, n_repeats=20, exposures=[4])
    args.captures = args.captures or [str(capture_or_default(None, args.quick))]
    args.methods = args.methods.split(',')
    args.learned_starts = args.learned_starts.split(',')
    results = {}
    old = json.load(open(args.reuse)) if args.reuse else {'args': {}, 'results': {}}
    if old['args'].get('seed', args.seed) != args.seed:
        raise SystemExit(f'--reuse: that run used split seed {old["args"]["seed"]}, not {args.seed}')
    for path in args.captures:
        args.reused = old['results'].get(path, {})
        results[path] = run_capture(path, args)
    print('\nheld-out accuracy (4 / 8 exposures), inner estimate - held-out (4 / 8), training '
          'seconds')
    for path, res in results.items():
        for name, r in res.items():
            secs = r['train_seconds'] or sum(v for k, v in r.items() if k.startswith('train_seconds_'))
            gap = ' / '.join(f'{r[f"estimate_{k}"] - r[k]:+.3f}' if f'estimate_{k}' in r and k in r
                             else '  n/a ' for k in ('4', '8'))
            print(f'{path:30s} {name:15s} {r.get("4", np.nan):.3f} / {r.get("8", np.nan):.3f}  '
                  f'gap {gap}  {secs:.0f} s'
                  + (f'  classify {r["classify_ms_8"]:.1f} ms' if 'classify_ms_8' in r else ''))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'args': {k: v for k, v in vars(args).items() if k != 'reused'},
                       'results': results}, f, indent=1)


if __name__ == '__main__':
    main()
