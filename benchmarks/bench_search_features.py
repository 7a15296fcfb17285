"""The greedy search's cost with each feature extractor, side by side in one run.

[1] ms per screened candidate (ridge screen, 400 splits, the second column), the extractors
    interleaved round by round so that every one sees the same machine load; median over
    the rounds, with the breakdown (render, noise, features, classifier) of the median round.
[2] (--full) the whole default search (per-colour, 8 columns, the exact-SVM race) once per
    extractor, one after the other: wall seconds.

    .venv/bin/python benchmarks/bench_search_features.py [--capture DIR] [--full]
    .venv/bin/python benchmarks/bench_search_features.py --quick   # [1] on a small capture

Without --capture it uses the default synthetic dataset of benchmarks/bench_search.py.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

import numpy as np
from bench_search import fmt_breakdown
from lightstage_physics.capture_format import load_capture
from mux_trainer.candidate_patterns import site_pattern_candidates
from mux_trainer.data import search_data
from mux_trainer.evaluation import CandidateEvaluator, score_candidate_chunk
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.search_params import Execution
from mux_trainer.rendering import compile_kernels

from _common import capture_or_default, parse_args


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--capture', help='capture folder (default: the synthetic dataset in .cache)')
    p.add_argument('--features', default='hog_grid,intensity_stats,pooled_hog_stats')
    p.add_argument('--noise', default='sigma3')
    p.add_argument('--candidates', type=int, default=16, help='candidates per round')
    p.add_argument('--rounds', type=int, default=5)
    p.add_argument('--jobs', type=int, default=2, help='--full: joblib workers')
    p.add_argument('--full', action='store_true', help='also the whole default search per extractor')
    args = parse_args(p, argv, candidates=2, rounds=1)
    names = [n.strip() for n in args.features.split(',') if n.strip()]

    capture = capture_or_default(args.capture, args.quick)
    base = search_data(load_capture(capture, downscale_to=120), args.noise)
    compile_kernels()
    print(f'data: {capture}: {base.n_samples} samples, {len(base.class_names)} classes; cpus '
          f'{os.cpu_count()}, load average {os.getloadavg()[0]:.1f}')
    W = site_pattern_candidates()
    prev = W[:, [37]]
    contexts = {}
    for name in names:
        ev = CandidateEvaluator(replace(base, features=name), n_repeats=400, seed=0)
        contexts[name] = (ev.data, ev.prepare_column(prev))
        score_candidate_chunk(*contexts[name], W[:, :1])  # warm up (caches, compiled code)
    seconds = {name: [] for name in names}
    breakdowns = {name: [] for name in names}
    n = args.candidates
    for r in range(args.rounds):
        for name in names:
            data, ctx = contexts[name]
            cands = W[:, 1 + r * n:1 + (r + 1) * n]
            timings: dict = {}
            t0 = time.perf_counter()
            score_candidate_chunk(data, ctx, cands, timings=timings)
            seconds[name].append((time.perf_counter() - t0) / cands.shape[1])
            breakdowns[name].append((timings, cands.shape[1]))
    print(f'\n[1] ms per screened candidate ({base.n_samples} samples x 4 images, 400 splits, '
          f'column 2; median of {args.rounds} interleaved rounds of {n})')
    reference = float(np.median(seconds[names[0]]))
    for name in names:
        med = int(np.argsort(seconds[name])[len(seconds[name]) // 2])
        t, count = breakdowns[name][med]
        value = float(np.median(seconds[name]))
        print(f'  {name:<18} {1e3 * value:7.1f} ms  ({value / reference:.2f} x {names[0]}; '
              f'{fmt_breakdown(t, count)})')

    if args.full:
        print(f'\n[2] the whole default search (per-colour, 8 columns, {args.jobs} workers), '
              'one extractor after the other')
        for name in names:
            t0 = time.perf_counter()
            model = GreedyPatternSelector(n_patterns=8, execution=Execution(n_jobs=args.jobs),
                                          seed=0).fit(
                replace(base, features=name))
            wall = time.perf_counter() - t0
            acc = ', '.join(f'{100 * model.accuracy_by_images_[k]:.1f}'
                            for k in sorted(model.accuracy_by_images_))
            print(f'  {name:<18} {wall:7.1f} s  (split accuracy by column count: {acc}); load '
                  f'average {os.getloadavg()[0]:.1f}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
