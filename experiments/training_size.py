"""How much of a fixed light's inner-minus-held-out gap is the training size, and does a
learning-curve step measured inside the training part predict it?

With 4 physical samples per class and one held out (`families_benchmark.sample_folds`, folds
0 and 1), a method is trained on 3 samples; its inner splits hold out 1 of those and train on
2. For the light each method keeps (naive: all LEDs; SNR-optimal's and greedy's fitted
columns, each then a fixed matrix, so no choice is in the figures), per fold:
- H3: held-out accuracy trained on the 3 samples (the benchmark's figure);
- I2: the inner estimate of the fixed light on the 3 samples (inner fits train on 2);
- H2, I1: the same trained on each pair of the 3 samples (held-out with 2 training
  samples; inner fits that train on 1), the mean over the 3 pairs;
- LC = I2 + (I2 - I1) / 3: the step from 2 to 3 training samples as a 1/n learning curve
  (error = a + b / n) extrapolates it from the step 1 -> 2.
Prints per family and the means of I2 - H3, LC - H3 and H3 - H2 at 4 / 8 exposures.

    PYTHONPATH=benchmarks:experiments .venv/bin/python experiments/training_size.py SEEDS [CACHE]
    # e.g. 0-7 (the tuning seeds), 100-119 (the report seeds)
"""
import itertools
import json
import sys
from types import SimpleNamespace

import numpy as np

import families_benchmark as fb
from mux_trainer.baselines import FixedPatternClassifier, NaiveClassifier, SnrOptimalClassifier
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.holdout import evaluate_heldout
from mux_trainer.search_params import SplitScoring

COLS = {'naive': {4: 1, 8: 1}, 'snr_optimal': {4: 1, 8: 2}, 'greedy': {4: 1, 8: 2}}


def fitted(name, train, scoring):
    if name == 'naive':
        return NaiveClassifier(scoring=scoring).fit(train)
    if name == 'snr_optimal':
        return SnrOptimalClassifier(n_images=2, scoring=scoring).fit(train)
    return GreedyPatternSelector(mode='per_colour', n_patterns=2, scoring=scoring).fit(train)


def fold_figures(train, test, scoring, n_renders=4):
    out = {}
    for name, cols in COLS.items():
        model = fitted(name, train, scoring)
        fixed = dict(patterns=model.patterns_, mode=model.mode, scoring=scoring)
        full = FixedPatternClassifier(**fixed).fit(train)
        h3 = evaluate_heldout(full, test, n_renders)['accuracy_by_images']
        i2 = full.accuracy_by_images_
        h2, i1 = [], []
        samples = np.unique(train.instance)
        for pair in itertools.combinations(samples, 2):
            sub = train.subset(np.flatnonzero(np.isin(train.instance, pair)))
            small = FixedPatternClassifier(**fixed).fit(sub)
            h2.append(evaluate_heldout(small, test, n_renders)['accuracy_by_images'])
            i1.append(small.accuracy_by_images_)
        out[name] = {}
        for e, c in cols.items():
            out[name][e] = {'H3': h3[c], 'I2': i2[c], 'H2': float(np.mean([h[c] for h in h2])),
                            'I1': float(np.mean([i[c] for i in i1]))}
    return out


def main(seeds, cache='out/families'):
    args = SimpleNamespace(strength=0.5, samples=4, poses=4, size=60, sample_spread=0.05,
                           cache=cache)
    scoring = SplitScoring(n_repeats=60, inner_groups='auto')
    rows = []
    for seed in fb.parse_seeds(seeds):
        data = fb.family_data(fb.family_capture(args, seed), 'intensity_stats', 60)
        folds = [fold_figures(train, test, scoring) for train, test in fb.sample_folds(data, (0, 1))]
        row = {m: {e: {k: float(np.mean([f[m][e][k] for f in folds])) for k in folds[0][m][e]}
                   for e in COLS[m]} for m in COLS}
        rows.append(row)
        print(seed, json.dumps(row), flush=True)
    print(f'over {len(rows)} families (points; LC = I2 + (I2 - I1) / 3):')
    for m in COLS:
        for e in (4, 8):
            f = {k: np.array([r[m][e][k] for r in rows]) * 100 for k in ('H3', 'I2', 'H2', 'I1')}
            lc = f['I2'] + (f['I2'] - f['I1']) / 3
            print(f'{m:12s} {e} exp: H3 {f["H3"].mean():5.1f}  H3-H2 {(f["H3"] - f["H2"]).mean():+5.1f}'
                  f'  I2-I1 {(f["I2"] - f["I1"]).mean():+5.1f}  I2-H3 {(f["I2"] - f["H3"]).mean():+5.1f}'
                  f'  LC-H3 {(lc - f["H3"]).mean():+5.1f}  |I2-H3| {np.abs(f["I2"] - f["H3"]).mean():4.1f}'
                  f'  |LC-H3| {np.abs(lc - f["H3"]).mean():4.1f}')


if __name__ == '__main__':
    main(*sys.argv[1:3])
