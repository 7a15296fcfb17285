"""Does the fast inner classifier (ridge, shared kernel) rank candidates like the linear SVM?

On our data (default: the synthetic dataset at Sigma3), for the first pattern column:
1. all 254 candidates are scored with ridge over 400 splits (the search's default);
2. a subset of candidates (ridge's top --top plus --random others, seeded) is scored with
   one LinearSVC per split on the first --svm-splits of the same splits, and with ridge on
   exactly those splits;
3. prints Spearman rank correlations (ridge vs SVM on the same splits; ridge-400 vs SVM),
   each method's winner within the subset, and where the SVM's winner ranks under ridge.

Both scorers see identical features (same renders, same noise, same splits), so the only
difference is the classifier. LinearSVC costs ~0.5-3 s per fit here, hence the subset.

Usage: .venv/bin/python benchmarks/rank_agreement.py [--capture DIR] [--noise sigma3]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('lightstage_camera', 'mux_classifier', 'mux_trainer'):
    sys.path.insert(0, str(ROOT / 'src' / pkg))

from lightstage_camera.capture_format import load_capture  # noqa: E402
from mux_trainer.data import search_data  # noqa: E402
from mux_trainer.evaluation import CandidateEvaluator  # noqa: E402
from mux_trainer.patterns import site_pattern_candidates  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--capture', default=str(ROOT / '.cache' / 'bench_synth'))
    p.add_argument('--noise', default='sigma3')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--top', type=int, default=12)
    p.add_argument('--random', type=int, default=20)
    p.add_argument('--svm-splits', type=int, default=16)
    p.add_argument('--jobs', type=int, default=2)
    args = p.parse_args(argv)

    data = search_data(load_capture(args.capture, downscale_to=120), args.noise)
    W = site_pattern_candidates()
    t0 = time.perf_counter()
    ridge_ev = CandidateEvaluator(data, n_repeats=400, seed=args.seed, n_jobs=args.jobs)
    ridge = ridge_ev.score(ridge_ev.prepare_column(None), W)
    print(f'{args.capture} at {args.noise}: ridge scored all {W.shape[1]} candidates x 400 '
          f'splits in {time.perf_counter() - t0:.0f} s')
    ridge400 = ridge.mean(axis=1)
    ridge_s = ridge[:, :args.svm_splits].mean(axis=1)  # the same first splits the SVM sees
    order = np.argsort(-ridge400, kind='stable')
    rng = np.random.default_rng(args.seed)
    rest = order[args.top:]
    subset = np.concatenate([order[:args.top],
                             rng.choice(rest, size=min(args.random, rest.size), replace=False)])
    t0 = time.perf_counter()
    svm_ev = CandidateEvaluator(data, n_repeats=args.svm_splits, seed=args.seed,
                                inner_classifier='linear_svm', n_jobs=args.jobs, chunk_size=4)
    svm = svm_ev.score(svm_ev.prepare_column(None), W[:, subset]).mean(axis=1)
    print(f'LinearSVC scored {subset.size} candidates x {args.svm_splits} splits in '
          f'{time.perf_counter() - t0:.0f} s (ridge top {args.top} + {args.random} random)')
    rho_same = spearmanr(ridge_s[subset], svm).statistic
    rho_400 = spearmanr(ridge400[subset], svm).statistic
    print(f'Spearman ridge vs LinearSVC, same {args.svm_splits} splits: {rho_same:.3f}')
    print(f'Spearman ridge (400 splits) vs LinearSVC ({args.svm_splits} splits): {rho_400:.3f}')
    code = lambda j: ''.join(str(int(v)) for v in W[:, j])  # noqa: E731
    best_r = subset[int(np.argmax(ridge400[subset]))]
    best_s = subset[int(np.argmax(svm))]
    rank_of_svm_best = int(np.flatnonzero(order == best_s)[0]) + 1
    print(f'winner ridge-400: {code(best_r)} (ridge {ridge400[best_r]:.4f}, SVM '
          f'{svm[subset == best_r][0]:.4f})')
    print(f'winner LinearSVC: {code(best_s)} (ridge {ridge400[best_s]:.4f}, SVM {svm.max():.4f}); '
          f'rank {rank_of_svm_best} of 254 under ridge; same winner: {best_r == best_s}')
    print(f'mean accuracy over the subset: ridge {ridge_s[subset].mean():.4f}, LinearSVC '
          f'{svm.mean():.4f} (same splits)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
