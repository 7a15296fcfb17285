"""Does the fast screen (ridge, shared kernel) rank candidates like the linear SVM?

On our data (default: the synthetic dataset at Sigma3), column after column of the paper's
per-colour greedy search, every one of the 254 candidates is scored over the same 400 splits,
renders and noise by
- the exact linear SVM (`SquaredHingeSplitScorer`: LinearSVC's problem solved to optimality,
  the paper's classifier), and
- ridge at each --alphas penalty (the search's screen; default 0.1),
and the script prints, per column and penalty: Spearman's rank correlation of the 254 scores,
where the SVM's winner ranks under ridge (1 = same winner) and how many SVM-accuracy points
ridge's own winner loses. For the search's screen (ridge at its default penalty) it then
replays the search's refinement race (`greedy.could_still_win`: the first 16 in ridge's
order, then 8 more at a time while one of the rest could still win, at most 64) at several
slacks, and says how many candidates the race refines and whether it keeps the SVM's
winner. The path followed is the exact SVM's greedy path, i.e. the default search's whenever
the race keeps the winner.

The last lines summarise over columns. --save writes every score to an .npz.

Usage: .venv/bin/python benchmarks/rank_agreement.py [--capture DIR] [--columns 8] [--jobs 2]
About 4 minutes per column on 2 cores (the SVM over 254 x 400 splits dominates).
--quick: 1 column, 10 splits, ridge 0.5 (the screen's), slack 0, on a small capture.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from joblib import Parallel, delayed
from scipy.stats import spearmanr
from threadpoolctl import threadpool_limits

from lightstage_physics.capture_format import load_capture
from mux_trainer.data import search_data
from mux_trainer.evaluation import CandidateEvaluator
from mux_trainer.greedy import (REFINE_BATCH, REFINE_MAX, REFINE_TOP,
                                could_still_win)
from mux_trainer.candidate_patterns import site_pattern_candidates
from mux_trainer.rendering import add_noise, clean_site_images, image_features
from mux_trainer.split_scoring import RidgeSplitScorer, SquaredHingeSplitScorer

from _common import capture_or_default, parse_args


def sites(pattern) -> str:
    """'00001111': which of the 8 sites a column lights."""
    return ''.join(str(int(v)) for v in pattern)


def score_chunk(data, ctx, candidates, scorers):
    """{name: (n_candidates,) mean split accuracy} for every scorer, on identical kernels."""
    out = {name: np.empty(candidates.shape[1]) for name in scorers}
    with threadpool_limits(limits=1, user_api='blas'):
        for j in range(candidates.shape[1]):
            clean = clean_site_images(data, candidates[:, j:j + 1])
            Xc = image_features(data, add_noise(data, clean, ctx.z))
            K = ctx.K_prev + (Xc @ Xc.T).astype(np.float64)
            for name, scorer in scorers.items():
                acc = scorer.split_accuracies(data.labels, ctx.test_masks, K=K,
                                              n_classes=ctx.n_classes)
                out[name][j] = acc.mean()
    return out


def replay_race(screen, svm, slack, top=REFINE_TOP, batch=REFINE_BATCH, cap=REFINE_MAX):
    """How many candidates the search's refinement race scores with the SVM (the same rule
    as `GreedyPatternSelector._choose`, on precomputed scores)."""
    order = np.argsort(-screen, kind='stable')
    k = min(top, order.size)
    while k < min(cap, order.size) and could_still_win(screen[order[:k]], svm[order[:k]],
                                                       screen[order[k]], slack):
        k = min(k + batch, order.size)
    return order[:k]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--capture', help='capture folder (default: the synthetic dataset, '
                   'generated once into .cache/bench_synth)')
    p.add_argument('--noise', default='sigma3')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--columns', type=int, default=8)
    p.add_argument('--alphas', default='0.1,0.5,2.0', help='ridge penalties to compare')
    p.add_argument('--slacks', default='0,1,2', help='refinement race slacks to replay')
    p.add_argument('--save', help='write all scores per column to this .npz')
    p.add_argument('--jobs', type=int, default=2)
    p.add_argument('--splits', type=int, default=400, help='splits per candidate (the search\'s 400)')
    args = parse_args(p, argv, columns=1, splits=10, alphas='0.5', slacks='0')

    alphas = [float(a) for a in args.alphas.split(',')]
    slacks = [float(v) for v in args.slacks.split(',')]
    capture = capture_or_default(args.capture, args.quick)
    data = search_data(load_capture(capture, downscale_to=120), args.noise)
    W = site_pattern_candidates()
    ev = CandidateEvaluator(data, n_repeats=args.splits, seed=args.seed)
    screen_name = f'ridge {ev.scorer.alpha:g}'
    if ev.scorer.alpha not in alphas:
        alphas.append(ev.scorer.alpha)
    race = {v: [] for v in slacks}
    saved = {}
    scorers = {'svm': SquaredHingeSplitScorer(C=1.0)}
    scorers.update({f'ridge {a:g}': RidgeSplitScorer(alpha=a) for a in alphas})
    print(f'{capture} at {args.noise}: {data.n_samples} samples, {W.shape[1]} candidates '
          f'x {args.splits} splits per column, exact linear SVM (C=1) vs ridge alpha {alphas}', flush=True)
    columns = np.zeros((data.n_sites, 0), np.float32)
    worst = {a: 0 for a in alphas}
    total_t = time.perf_counter()
    with Parallel(n_jobs=args.jobs) as parallel:
        for col in range(args.columns):
            t0 = time.perf_counter()
            ctx = ev.prepare_column(columns if col else None)
            parts = parallel(delayed(score_chunk)(data, ctx, W[:, b:b + 8], scorers)
                             for b in range(0, W.shape[1], 8))
            scores = {name: np.concatenate([part[name] for part in parts]) for name in scorers}
            svm = scores['svm']
            win = int(np.argmax(svm))
            print(f'column {col + 1}: SVM winner {sites(W[:, win])} '
                  f'(SVM {svm[win]:.4f}); {time.perf_counter() - t0:.0f} s', flush=True)
            for a in alphas:
                r = scores[f'ridge {a:g}']
                order = np.argsort(-r, kind='stable')
                rank = int(np.flatnonzero(order == win)[0]) + 1
                worst[a] = max(worst[a], rank)
                rho = spearmanr(r, svm).statistic
                print(f'  ridge {a:<4g}: Spearman {rho:.3f}; SVM winner is ridge\'s #{rank:<3d}; '
                      f'ridge winner {sites(W[:, order[0]])} loses '
                      f'{100 * (svm[win] - svm[order[0]]):.2f} SVM points', flush=True)
            for v in slacks:
                refined = replay_race(scores[screen_name], svm, v)
                kept = win in refined
                race[v].append((refined.size, kept))
                print(f'  race ({screen_name} screen, slack {v:g}): refines {refined.size:3d}, '
                      f'keeps the SVM winner: {kept}', flush=True)
            saved.update({f'c{col + 1}_{name}': arr for name, arr in scores.items()})
            columns = np.hstack([columns, W[:, [win]]])
    print(f'worst rank of the SVM winner under ridge over {args.columns} columns: ' +
          ', '.join(f'alpha {a:g}: #{worst[a]}' for a in alphas))
    for v in slacks:
        sizes = [k for k, _ in race[v]]
        print(f'race at slack {v:g}: keeps the SVM winner in {sum(kept for _, kept in race[v])} '
              f'of {len(race[v])} columns; refines {min(sizes)}..{max(sizes)} candidates per '
              f'column, {sum(sizes)} in all')
    if args.save:
        np.savez(args.save, candidates=W, path=columns, **saved)
        print(f'scores written to {args.save}')
    print(f'{(time.perf_counter() - total_t) / 60:.1f} min')
    return 0


if __name__ == '__main__':
    sys.exit(main())
