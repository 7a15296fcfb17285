"""Speed of the greedy pattern search: optimized path vs the straightforward reference.

Prints, from one run on the same data:
1. time per candidate evaluation of the optimized path (Gray-code rendering, float32 noise
   shared by the column's candidates, batched HOG, ridge with one kernel for all splits; and
   the exact linear SVM in kernel form that re-scores the screen's top candidates) and
   of the straightforward reference (per-image `L @ w`, float64 noise, skimage HOG per image,
   one LinearSVC per split), each with its breakdown (render, noise, features, classifier).
   The reference's classifier time is measured on --ref-splits splits and scaled to 400
   (said so in the output); everything else is measured.
2. the measured wall time of the full default search: paper's per-colour mode, 8 columns x
   254 candidates x 400 splits, on the capture (default: the synthetic dataset, 10 classes
   x 20 poses), with --jobs workers.
3. the columns selected by the optimized path (the default search: ridge screen, then the
   exact SVM's race down the screen's order) and by the reference (skimage HOG, LinearSVC per
   split, over every candidate) on a reduced problem (the first --check-sites sites,
   --check-splits splits, --check-columns columns, same seeds), side by side. The reference
   runs its candidates on --jobs workers (the same random numbers whatever the split).

The features of [1] are timed three ways on the same noisy images of one candidate: the
compiled kernel (`hog_batch`, the search's), the pure-numpy reference (`hog_batch_numpy`,
the search's extractor before the kernel) and skimage (on --skimage-images images, scaled).

With --old-svm REV, [1] also times the exact SVM of git revision REV (e.g. e656e38, before
the Newton loop moved into one compiled kernel) on the same candidates, interleaved.

Usage (what docs/SEARCH.md reports; [3] adds ~20 min, so it is skipped here):
    .venv/bin/python benchmarks/bench_search.py --jobs 2 --skip-check [--capture DIR] [--old-svm REV]
Without --capture the synthetic dataset (the same as `make demo`'s) is generated once into
.cache/bench_synth (`lightstage synth`, about 2-3 minutes on 2 cores); `--quick` measures
[1] and [3] on a small capture instead and skips [2]. Timings on a machine
shared with other work are inflated: the load average is printed at the start and the end.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from lightstage_physics.capture_format import load_capture
from mux_classifier.hog import hog_batch, hog_batch_numpy, hog_reference
from threadpoolctl import threadpool_limits
from mux_trainer.data import search_data
from mux_trainer.evaluation import CandidateEvaluator, score_candidate_chunk
from mux_trainer.greedy import REFINE_TOP, GreedyPatternSelector
from mux_trainer.candidate_patterns import site_pattern_candidates
from mux_trainer.reference import reference_candidate_scores
from mux_trainer.search_params import Execution, SplitScoring
from mux_trainer.rendering import SearchData, add_noise, clean_site_images

from _common import ROOT, capture_or_default, parse_args

PAPER_SPLITS = 400
# the default search's columns (sites lit, site 0 first) on the default synthetic dataset,
# noise sigma3, seed 0, as recorded in docs/SEARCH.md before the compiled kernel
RECORDED_COLUMNS = ('10001111', '00011111', '10001111', '10001111', '00001011', '10011111',
                    '00001101', '10001111')


def fmt_breakdown(t: dict, n: int, scale_classifier: float = 1.0) -> str:
    parts = {k: 1e3 * v / n for k, v in t.items()}
    if 'classifier' in parts:
        parts['classifier'] *= scale_classifier
    return ', '.join(f'{k} {v:8.1f} ms' for k, v in parts.items())


def revision_module(rev: str, path: str):
    """The module at `path` as of git revision `rev` of this repository (for timing an old
    implementation next to the current one)."""
    import importlib.util
    import subprocess
    import tempfile
    text = subprocess.run(['git', '-C', str(ROOT), 'show', f'{rev}:{path}'], check=True,
                          capture_output=True, text=True).stdout
    file = Path(tempfile.mkdtemp()) / f'{Path(path).stem}_{rev}.py'
    file.write_text(text)
    spec = importlib.util.spec_from_file_location(file.stem, file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def sites_subset(data: SearchData, n_sites: int) -> SearchData:
    return dataclasses.replace(data, basis=data.basis[:n_sites])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--capture', help='capture folder (default: synthetic dataset in .cache)')
    p.add_argument('--noise', default='sigma3')
    p.add_argument('--jobs', type=int, default=2)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--fast-candidates', type=int, default=32)
    p.add_argument('--ref-candidates', type=int, default=2)
    p.add_argument('--ref-splits', type=int, default=8)
    p.add_argument('--check-sites', type=int, default=6)
    p.add_argument('--check-splits', type=int, default=20)
    p.add_argument('--check-columns', type=int, default=2)
    p.add_argument('--old-svm', metavar='REV',
                   help='also time the exact SVM of git revision REV on the same candidates')
    p.add_argument('--skip-full', action='store_true', help='skip the full default search')
    p.add_argument('--skip-check', action='store_true', help='skip the reduced-problem check')
    p.add_argument('--skimage-images', type=int, default=40,
                   help='images timed with skimage for [1] (scaled to a candidate)')
    args = parse_args(p, argv, fast_candidates=4, ref_candidates=1, ref_splits=2, skip_full=True,
                      check_sites=3, check_splits=4, check_columns=1, skimage_images=4)

    capture = capture_or_default(args.capture, args.quick)
    t0 = time.perf_counter()
    data = search_data(load_capture(capture, downscale_to=120), args.noise)
    print(f'data: {capture}: {data.n_samples} samples, {len(data.class_names)} classes, '
          f'{len(np.unique(data.pose_index))} pose indices, {data.image_shape} px, noise '
          f'{args.noise}; loaded in {time.perf_counter() - t0:.1f} s; cpus {os.cpu_count()}, '
          f'load average {os.getloadavg()[0]:.1f}')
    W = site_pattern_candidates()
    prev = W[:, [37]]  # time the second column: one earlier column in the kernel

    # the compiled kernels load from numba's cache (or compile, the first time on a machine)
    t0 = time.perf_counter()
    hog_batch(np.zeros((1,) + data.image_shape, np.float32), data.hog_config)
    add_noise(data, np.zeros((1, 4), np.float32), np.zeros((1, 4), np.float32))
    print(f'compiled kernels ready in {time.perf_counter() - t0:.2f} s (first call in this '
          'process: a cache load, or a compile of ~5-8 s the first time on a machine)')

    # 1a. optimized path, one worker, one chunk of candidates
    ev = CandidateEvaluator(data, n_repeats=PAPER_SPLITS, seed=args.seed)
    t0 = time.perf_counter()
    ctx = ev.prepare_column(prev)
    prep = time.perf_counter() - t0
    n_fast = args.fast_candidates
    t_fast: dict = {}
    t0, c0 = time.perf_counter(), time.process_time()
    score_candidate_chunk(data, ctx, W[:, :n_fast], timings=t_fast)
    fast_total = (time.perf_counter() - t0) / n_fast
    fast_cpu = (time.process_time() - c0) / n_fast
    print(f'\n[1] time per candidate evaluation ({data.n_samples} samples x 4 images, '
          f'{PAPER_SPLITS} splits, column 2)')
    print(f'  optimized  : {1e3 * fast_total:9.1f} ms   ({fmt_breakdown(t_fast, n_fast)}); '
          f'column set-up {1e3 * prep:.0f} ms once per column ({1e3 * prep / 254:.1f} ms per candidate)')
    # the same candidate's features by the previous extractors, on its noisy images
    images = add_noise(data, clean_site_images(data, W[:, :1]), ctx.z)
    flat = images.reshape(-1, *data.image_shape)
    t_feat = {}
    with threadpool_limits(limits=1, user_api='blas'):
        for name, fn, count in (
                ('compiled kernel (hog_batch)', lambda x: hog_batch(x, data.hog_config), len(flat)),
                ('numpy reference (hog_batch_numpy)',
                 lambda x: hog_batch_numpy(x, replace(data.hog_config, batch_size=2)), len(flat)),
                ('skimage.feature.hog per image',
                 lambda x: [hog_reference(img, data.hog_config) for img in x],
                 args.skimage_images)):
            t0 = time.perf_counter()
            fn(flat[:count])
            t_feat[name] = (time.perf_counter() - t0) * len(flat) / count
    features_now = t_fast['features'] / n_fast
    for name, seconds in t_feat.items():
        total = fast_total - features_now + seconds
        print(f'  features by {name:<34}: {1e3 * seconds:7.1f} ms per candidate ({len(flat)} '
              f'images) -> {1e3 * total:6.1f} ms per screened candidate'
              + (f' (timed on {args.skimage_images} images)' if 'skimage' in name else ''))
    print(f'               CPU time {1e3 * fast_cpu:.1f} ms per candidate (one BLAS thread): on an '
          f'idle machine the 8 x 254 candidates need ~{8 * 254 * fast_cpu / 60:.1f} CPU-minutes, '
          f'~{8 * 254 * fast_cpu / 120:.1f} min of wall time on 2 cores (estimate; the measured '
          'wall time is in [2])')

    # 1a'. the refinement's exact SVM on the same candidates' kernels
    from mux_trainer.split_scoring import SquaredHingeSplitScorer
    n_svm = min(8, n_fast)
    t_svm: dict = {}
    t0 = time.perf_counter()
    for j in range(n_svm):
        score_candidate_chunk(data, dataclasses.replace(ctx, scorer=SquaredHingeSplitScorer()),
                              W[:, j:j + 1], timings=t_svm)
    svm_total = (time.perf_counter() - t0) / n_svm
    print(f'  exact SVM  : {1e3 * svm_total:9.1f} ms   per refined candidate '
          f'({fmt_breakdown(t_svm, n_svm)}: LinearSVC\'s problem solved exactly for all '
          f'{PAPER_SPLITS} splits); the race refines 16 to 64 of 254 per column (counts in [2])')
    if args.old_svm:
        # the same candidates scored by the exact SVM of another revision, interleaved with
        # this one's so that both see the same load
        old = revision_module(args.old_svm, 'src/mux_trainer/mux_trainer/split_scoring.py')
        scorers = {'this': SquaredHingeSplitScorer(), args.old_svm: old.SquaredHingeSplitScorer()}
        for scorer in scorers.values():   # compile (or load) the kernels outside the timing
            score_candidate_chunk(data, dataclasses.replace(ctx, scorer=scorer,
                                                            test_masks=ctx.test_masks[:2]),
                                  W[:, :1])
        cpu = dict.fromkeys(scorers, 0.0)
        same = True
        for j in range(n_svm):
            acc = {}
            for name, scorer in scorers.items():
                t = {}
                acc[name] = score_candidate_chunk(
                    data, dataclasses.replace(ctx, scorer=scorer), W[:, j:j + 1], timings=t)
                cpu[name] += t['classifier']
            same &= np.array_equal(*acc.values())
        print(f'  exact SVM classifier, this revision vs {args.old_svm} on the same {n_svm} '
              f'candidates (interleaved): ' + ' vs '.join(
                  f'{1e3 * v / n_svm:.1f} ms' for v in cpu.values())
              + f' per candidate ({cpu[args.old_svm] / cpu["this"]:.2f}x); identical split '
              f'accuracies: {same}')

    # 1b. straightforward reference on a few candidates, classifier on fewer splits
    t_ref: dict = {}
    n_ref = args.ref_candidates
    reference_candidate_scores(data, 'per_colour', prev, W[:, :n_ref], seed=args.seed,
                               n_repeats=args.ref_splits, classifier='linear_svm',
                               timings=t_ref)
    scale = PAPER_SPLITS / args.ref_splits
    ref_total = (t_ref['render_noise'] + t_ref['features'] + t_ref['classifier'] * scale) / n_ref
    print(f'  reference  : {1e3 * ref_total:9.1f} ms   ({fmt_breakdown(t_ref, n_ref, scale)}); '
          f'classifier measured on {args.ref_splits} LinearSVC fits per candidate and scaled '
          f'x{scale:g} to {PAPER_SPLITS} splits')
    for k in (16, 64):
        per_candidate = fast_total + prep / 254 + svm_total * k / 254
        print(f'  speed-up   : {ref_total / per_candidate:9.0f} x per candidate with {k} refined '
              f'per column, spread over its 254 ({1e3 * per_candidate:.1f} ms; target >= 100 x)')
    print(f'               screen alone {ref_total / (fast_total + prep / 254):.0f} x; exact SVM '
          f'alone {ref_total / svm_total:.0f} x (both against the reference per candidate)')
    ref_search_days = ref_total * 8 * 254 / 86400
    print(f'  reference full search (8 x 254 candidates) would take ~{ref_search_days:.1f} days '
          'on one core')

    # 2. the full default search, measured
    if not args.skip_full:
        print(f'\n[2] full default search: per-colour, 8 columns x 254 candidates x '
              f'{PAPER_SPLITS} splits, {args.jobs} worker(s)', flush=True)
        t0 = time.perf_counter()
        sel = GreedyPatternSelector(n_patterns=8, scoring=SplitScoring(n_repeats=PAPER_SPLITS),
                                    seed=args.seed,
                                    execution=Execution(n_jobs=args.jobs, progress=True)).fit(data)
        wall = time.perf_counter() - t0
        screen = sum(h['screen_seconds'] for h in sel.history_)
        refine = sum(h['refine_seconds'] for h in sel.history_)
        print(f'  wall time  : {wall:9.1f} s = {wall / 60:.2f} min (target <= 4 min): screen '
              f'{screen:.0f} s, SVM refinement {refine:.0f} s, the rest (column set-up, 8 final '
              f'LinearSVC classifiers) {wall - screen - refine:.0f} s; load average now '
              f'{os.getloadavg()[0]:.1f}')
        ranks = [int(np.flatnonzero(h['refined'] == h['best'])[0]) + 1 for h in sel.history_]
        print(f'  candidates refined per column: {[len(h["refined"]) for h in sel.history_]}; '
              f'screen rank of each chosen column: {ranks} (1 = ridge alone would have chosen it)')
        acc = ', '.join(f'{k}: {v:.4f}' for k, v in sel.accuracy_by_images_.items())
        print(f'  split accuracy by image count: {acc}')
        columns = tuple(''.join(str(int(v)) for v in col) for col in sel.patterns_.T)
        print('  columns (sites lit): ' + ' | '.join(columns))
        if args.noise == 'sigma3' and args.seed == 0:
            print(f'  same columns as recorded before the compiled kernel on the default '
                  f'dataset '
                  f'({" | ".join(RECORDED_COLUMNS)}): {columns == RECORDED_COLUMNS}')

    # 3. reduced problem: same columns as the reference?
    if not args.skip_check:
        from joblib import Parallel, delayed
        from scipy.stats import spearmanr
        small = sites_subset(data, args.check_sites)
        cands = site_pattern_candidates(args.check_sites)
        print(f'\n[3] reduced problem: first {args.check_sites} sites ({cands.shape[1]} '
              f'candidates), {args.check_splits} splits, {args.check_columns} columns, seed '
              f'{args.seed}; optimized = the default search (ridge screen, exact SVM race from '
              f'its top {REFINE_TOP}), reference = skimage HOG and one LinearSVC per split for '
              f'every candidate', flush=True)
        fast = GreedyPatternSelector(n_patterns=args.check_columns,
                                     scoring=SplitScoring(n_repeats=args.check_splits),
                                     seed=args.seed,
                                     execution=Execution(n_jobs=args.jobs)).fit(small)
        cols = np.zeros((args.check_sites, 0), np.float32)
        ref_cols = []
        t0 = time.perf_counter()
        for j in range(args.check_columns):
            chunks = [cands[:, b:b + 4] for b in range(0, cands.shape[1], 4)]
            acc = np.vstack(Parallel(n_jobs=args.jobs)(
                delayed(reference_candidate_scores)(small, 'per_colour', cols if j else None, c,
                                                    seed=args.seed, n_repeats=args.check_splits,
                                                    classifier='linear_svm')
                for c in chunks)).mean(axis=1)
            best = int(np.argmax(acc))
            cols = np.hstack([cols, cands[:, [best]]])
            ref_cols.append(cands[:, best])
            h = fast.history_[j]
            rho = spearmanr(h['scores'], acc).statistic
            same_svm = np.array_equal(h['refined_scores'], acc[h['refined']])
            rank = int(np.flatnonzero(np.argsort(-h['scores'], kind='stable') == best)[0]) + 1
            ties = int(np.sum(acc == acc[best]))
            print(f'  column {j + 1}: optimized {"".join(str(int(v)) for v in fast.patterns_[:, j])} '
                  f'acc {h["accuracy"]:.4f} | reference {"".join(str(int(v)) for v in cands[:, best])} '
                  f'acc {acc[best]:.4f} ({ties} candidate(s) at that score) | the race refined '
                  f'{len(h["refined"])}; the reference winner is the screen\'s #{rank}; exact SVM '
                  f'scores of the refined equal the reference\'s: {same_svm}; Spearman ridge vs '
                  f'reference over all {cands.shape[1]}: {rho:.3f}', flush=True)
        same = all(np.array_equal(a, b) for a, b in zip(fast.patterns_.T, ref_cols))
        print(f'  identical columns: {same}   (reference took {time.perf_counter() - t0:.0f} s '
              f'on {args.jobs} worker(s))')
    return 0


if __name__ == '__main__':
    sys.exit(main())
