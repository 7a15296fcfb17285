"""The learned model's final head refitted on the light a benchmark run kept: held-out
accuracy with the head fitted on 1 and on more noise draws of the training samples
(`LearnedIlluminationClassifier(head_renders=...)`), nothing else changed.

The light is read from JSONs of learned_vs_greedy.py or learned_strength_sweep.py (several
runs of the same split are joined as learned_combine_descents.py joins them: the candidate
one fit of all their descents keeps), then the estimator is fitted with that light as its
only start and no descent: it scores it on the inner splits and fits the head. With
head_renders 1 this gives the run's own held-out figure (the check printed as "run"; the
JSONs store the levels to 3 decimals). Captures: a learned_vs_greedy run names them; a
sweep run's are SWEEP_DIR/weakS (its `out`). Held-out poses or instances, split seed and
test renders as the run had them.

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer \\
        .venv/bin/python benchmarks/learned_refit_head.py r4_poses.json r5_poses.json --head-renders 1,4

--other-heads also fits, on the same light, heads the learned model does not have (a probe of
what another head would add; scikit-learn, on the standardised statistics of 6 noise draws of
the training samples): the linear SVM as the model's (one-vs-rest), an RBF SVM (C 100), a
64-unit MLP (alpha 1e-3), and three other linear heads: one-vs-one linear SVMs (a classifier
per pair of classes), multinomial logistic regression, and object type first, then a linear
SVM per type for its variants (`TypeThenVariant`, types from the class names' "type-variant").
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin

from mux_trainer.holdout import test_features
from mux_trainer.learned import (Descent, Head, LearnedIlluminationClassifier, Starts,
                                 evaluate_learned_heldout)
from mux_trainer.search_params import SplitScoring

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from learned_combine_descents import combine, learned_runs
from learned_vs_greedy import split_capture


def capture_and_seed(key: str, run_args: dict) -> tuple[str, int]:
    """A result key of a run -> (capture folder, split seed)."""
    if 'strengths' in run_args:            # a sweep: 'S/seed' under its out folder
        strength, seed = key.split('/')
        return os.path.join(run_args['out'], f'weak{strength}'), int(seed)
    return key, int(run_args['seed'])


OTHER_HEADS = ('linear_svm', 'rbf_svm', 'mlp64', 'ovo_linear_svm', 'logistic', 'type_then_variant')


class TypeThenVariant(BaseEstimator, ClassifierMixin):
    """A linear SVM for the object type (the class name before its first '-'), then one per
    type for its variants (real / fake): each pair gets a classifier of its own."""

    def __init__(self, class_names, C=1.0):
        self.class_names, self.C = class_names, C

    def fit(self, X, y):
        from sklearn.svm import LinearSVC
        names = dict.fromkeys(n.split('-')[0] for n in self.class_names)
        type_of = np.array([list(names).index(n.split('-')[0]) for n in self.class_names])
        t = type_of[y]
        self.type_head_ = LinearSVC(C=self.C, max_iter=20000).fit(X, t)
        self.heads_ = {ty: (LinearSVC(C=self.C, max_iter=20000).fit(X[t == ty], y[t == ty])
                            if np.unique(y[t == ty]).size > 1 else int(y[t == ty][0]))
                       for ty in np.unique(t)}
        return self

    def predict(self, X):
        t = self.type_head_.predict(X)
        out = np.empty(len(X), np.int64)
        for ty in np.unique(t):
            head = self.heads_[ty]
            out[t == ty] = head.predict(X[t == ty]) if hasattr(head, 'predict') else head
        return out


def other_heads(train, test, light, seed, n_renders, train_instance, draws=6) -> dict:
    """Held-out accuracy of each of OTHER_HEADS fitted on `draws` noise draws of the training
    samples' statistics under `light` (the test-noise stream's generator at render indices
    100.., samples the test never has), tested on the run's test renders; and, as a criterion
    that could choose the head from the training samples alone, its leave-one-instance-out
    accuracy on them (`{head}_inner_by_instance`: fitted without physical sample number u of
    every class, scored on it, mean over u)."""
    from sklearn.base import clone
    from sklearn.linear_model import LogisticRegression
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC, LinearSVC
    X = np.vstack([test_features(train, 'joint', light, 100 + r, seed) for r in range(draws)])
    y = np.tile(train.labels, draws)
    tests = [test_features(test, 'joint', light, r, seed) for r in range(n_renders)]
    heads = {'linear_svm': LinearSVC(C=1.0, max_iter=20000), 'rbf_svm': SVC(C=100.0),
             'mlp64': MLPClassifier((64,), alpha=1e-3, max_iter=2000, random_state=0),
             'ovo_linear_svm': SVC(kernel='linear', C=1.0),
             'logistic': LogisticRegression(C=1.0, max_iter=5000),
             'type_then_variant': TypeThenVariant(list(train.class_names))}
    out = {}
    for name in OTHER_HEADS:
        inner = []
        for u in np.unique(train_instance):
            kept = np.tile(train_instance != u, draws)
            head = make_pipeline(StandardScaler(), clone(heads[name])).fit(X[kept], y[kept])
            inner.append(np.mean(head.predict(X[~kept]) == y[~kept]))
        out[f'{name}_inner_by_instance'] = float(np.mean(inner))
        head = make_pipeline(StandardScaler(), heads[name]).fit(X, y)
        predicted = [head.predict(t) for t in tests]
        out[name] = float(np.mean([p == test.labels for p in predicted]))
        wrong = {}
        for p in predicted:
            for truth, answer in zip(test.labels[p != test.labels], p[p != test.labels]):
                pair = f'{test.class_names[truth]} -> {test.class_names[answer]}'
                wrong[pair] = wrong.get(pair, 0) + 1
        out[f'{name}_errors'] = dict(sorted(wrong.items(), key=lambda kv: -kv[1]))
    print(f'  linear SVM errors over the {n_renders} test renders: {out["linear_svm_errors"]}')
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('runs', nargs='+', help='JSONs of the same split(s), joined per capture')
    p.add_argument('--head-renders', default='1,4', help='comma-separated draws to compare')
    p.add_argument('--exposures', default='4,8')
    p.add_argument('--order', default='random,greedy', help="the descents, in the fit's order")
    p.add_argument('--other-heads', action='store_true', help='also fit ' + ', '.join(OTHER_HEADS))
    p.add_argument('--json', help='write the figures here')
    args = p.parse_args(argv)
    run_args = json.load(open(args.runs[0]))['args']
    renders = [int(r) for r in args.head_renders.split(',')]
    out = {}
    for key, runs in learned_runs(args.runs).items():
        path, seed = capture_and_seed(key, run_args)
        train, test, train_instance = split_capture(path, run_args['holdout_by'], seed)
        for k in args.exposures.split(','):
            if not all(f'inner_{k}' in r['learned'] for r in runs):
                continue
            best, _inner, accuracy = combine(runs, k, args.order.split(','))
            kept_by = next(r for r in runs if r['learned'][f'chosen_{k}'] == best)
            light = np.array(kept_by['learned'][f'patterns_{k}'], np.float32)
            row = {'kept': best, 'run': accuracy, 'greedy': kept_by.get('greedy', {}).get(k)}
            for h in renders:
                model = LearnedIlluminationClassifier(
                    n_images=int(k), starts=Starts(names=(), patterns={best: light}),
                    descent=Descent(fine_tune='none'), head=Head(renders=h),
                    scoring=SplitScoring(n_repeats=run_args.get('n_repeats', 400)),
                    seed=seed).fit(train)
                row[h] = evaluate_learned_heldout(model, test, run_args.get('n_renders', 4),
                                                  seed)['accuracy']
            if args.other_heads:
                row.update(other_heads(train, test, light, seed, run_args.get('n_renders', 4),
                                       train_instance))
            out[f'{key} {k}'] = row
            print(f'{key}, {k} exposures, kept {best}: run {100 * accuracy:.1f} %; ' + ', '.join(
                f'head_renders {h}: {100 * row[h]:.1f} %' for h in renders) + ''.join(
                f', {name}: {100 * row[name]:.1f} % (inner by instance '
                f'{100 * row[f"{name}_inner_by_instance"]:.1f})' for name in OTHER_HEADS if name in row),
                flush=True)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(out, f, indent=1)


if __name__ == '__main__':
    main()
