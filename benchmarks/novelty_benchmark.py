"""Unknown objects: an object type never trained, presented to the novelty score.

For each capture seed, `lightstage synth` renders every object type (the five fruit and the
three flat objects, real and fake: 16 classes) with --samples physical samples per class and
--poses poses, at 120 px. Each type in turn is left out of training: the novelty models
(`mux_classifier.novelty.NoveltyModel`, as `lightstage train` fits them,
`mux_trainer.novelty_fit`: intensity statistics of --train-renders noisy renders of every
training sample, threshold at --false-alarm-rate on held-out physical samples) are fitted on
the other types, with physical sample number f of every class held out too (fold f of
--samples). Then fresh Sigma3 renders (noise drawn apart from the training's) are scored:

- detected: the share of the left-out type's renders flagged unknown (score >= 1);
- false alarms: the share of renders of the held-out physical samples of the known types
  flagged unknown (new samples of trained types: what a user puts on the stage);
- families: the share of renders of procedural families (`lightstage_physics.families`:
  random shapes of the synthetic stage with random materials, types nobody tuned on) flagged.

The patterns are the per-colour S-code (`snr_optimal.s_matrix_for_sites`), its first
--columns columns (4 images each); every image count 4, 8, ... is reported. The method was
chosen on --tune-seeds; --report-seeds are the figures to quote (docs/NOVELTY.md).
--compare also scores the alternatives on the tune seeds (features: intensity statistics or
the HOG grid; scores: this Mahalanobis distance, a kNN distance, an isolation forest, a
one-class SVM), all thresholded alike: the plain (1 - rate) quantile of held-out groups.

    .venv/bin/python benchmarks/novelty_benchmark.py            # about 5 min on 2 cores
    .venv/bin/python benchmarks/novelty_benchmark.py --compare  # + the alternatives
    .venv/bin/python benchmarks/novelty_benchmark.py --quick    # make bench: 3 types, 1 seed each
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import parse_args as parse_with_quick
from mux_trainer.novelty_fit import UNKNOWN_TEST_STREAM as TEST_STREAM  # the test renders' noise


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--tune-seeds', default='0,1,2',
                   help='capture seeds the method was chosen on (0,1,2)')
    p.add_argument('--report-seeds', default='3,4', help='capture seeds to report on (3,4)')
    p.add_argument('--samples', type=int, default=5, help='physical samples per class (5)')
    p.add_argument('--poses', type=int, default=4, help='poses per sample (4)')
    p.add_argument('--types', default='', help='object types (default: all eight)')
    p.add_argument('--families', default='0,1,2,3,4,5', help='family seeds (0..5)')
    p.add_argument('--columns', type=int, default=4,
                   help='S-code pattern columns, 4 images each (4: 16 exposures)')
    p.add_argument('--train-renders', type=int, default=3, help='noisy renders per training sample (3)')
    p.add_argument('--test-renders', type=int, default=2, help='noisy renders per test sample (2)')
    p.add_argument('--false-alarm-rate', type=float, default=0.05, help='stated rate (0.05)')
    p.add_argument('--compare', action='store_true', help='also score the alternatives')
    p.add_argument('--work-dir', help='where to write the captures (default: a temporary folder)')
    p.add_argument('--jobs', type=int, default=1, help='render jobs (1)')
    p.add_argument('--json', help='write every figure to this file')
    return parse_with_quick(p, argv, tune_seeds='0', report_seeds='1', samples=2, poses=2,
                            types='banana,orange,coin', families='0', columns=2, train_renders=1,
                            test_renders=1)


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(',') if x.strip()]


def make_inputs(work: Path, seeds, families, args):
    """Captures (one per seed) and families, written once into `work`."""
    from lightstage_physics import families as fam
    from lightstage_physics import synth
    types = tuple(args.types.split(',')) if args.types else synth.ALL_OBJECT_TYPES
    for seed in seeds:
        out = work / f'capture_{seed}'
        if not out.exists():
            synth.generate(out, image_size=120, n_samples_per_class=args.samples,
                           n_poses=args.poses, seed=seed, object_types=types, n_jobs=args.jobs)
    for f in families:
        out = work / f'family_{f}'
        if not out.exists():
            fam.generate_family(out, f, n_samples_per_class=3, n_poses=3, image_size=120,
                                n_jobs=args.jobs)


def _data(path: Path):
    from mux_trainer.data import search_data
    from mux_trainer.training import load_training_set
    return search_data(load_training_set(path), 'sigma3')


def _features(data, patterns, renders: int, seed: int, stream: int, extractor=None):
    """`renders` noisy renders of every sample: a list of (n, features) (default: the
    novelty models' features)."""
    from mux_trainer.novelty_fit import novelty_features
    extra = {} if extractor is None else {'features': extractor}
    return [novelty_features(data, 'per_colour', patterns, r, seed, stream, **extra)
            for r in range(renders)]


def measure(seed: int, work: Path, family_seeds, args, patterns) -> dict:
    """Every fold's figures for one capture seed, per image count."""
    from lightstage_physics.scene_models import object_type_of
    from mux_classifier.novelty import NoveltyModel
    from mux_trainer.novelty_fit import NOVELTY_STREAM, sample_groups

    data = _data(work / f'capture_{seed}')
    types = np.array([object_type_of(c) for c in data.class_names])[data.labels]
    inst = data.instance
    train = np.stack(_features(data, patterns, args.train_renders, seed, NOVELTY_STREAM))
    test = np.stack(_features(data, patterns, args.test_renders, seed, TEST_STREAM))
    fams = [np.vstack(_features(_data(work / f'family_{f}'), patterns, args.test_renders,
                                seed, TEST_STREAM)) for f in family_seeds]
    groups = sample_groups(data)
    per_image = train.shape[2] // (4 * patterns.shape[1])
    counts = [4 * c for c in range(1, patterns.shape[1] + 1)]
    rows = []
    for left_out in dict.fromkeys(types.tolist()):
        for fold in range(int(inst.max()) + 1):
            fit = (types != left_out) & (inst != fold)
            known = (types != left_out) & (inst == fold)
            unknown = types == left_out
            for k in counts:
                width = k * per_image
                X = train[:, fit, :width].reshape(-1, width)
                model = NoveltyModel().fit(X, np.tile(data.labels[fit], len(train)),
                                           np.tile(groups[fit], len(train)),
                                           args.false_alarm_rate)

                def flagged(Z):
                    return float((model.score(Z.reshape(-1, Z.shape[-1])[:, :width]) >= 1).mean())
                rows.append({'seed': seed, 'left_out': left_out, 'fold': fold, 'images': k,
                             'detected': flagged(test[:, unknown]),
                             'false_alarm': flagged(test[:, known]),
                             'families': [flagged(f) for f in fams],
                             'held_out_false_alarm': model.held_out_false_alarm_})
    return {'rows': rows, 'class_names': list(data.class_names)}


def summarise(rows: list[dict]) -> dict:
    """Per image count: detection (mean, worst left-out type), false alarms (mean, worst
    fold), families (mean, worst family)."""
    out = {}
    for k in sorted({r['images'] for r in rows}):
        rk = [r for r in rows if r['images'] == k]
        by_type = {}
        for r in rk:
            by_type.setdefault(r['left_out'], []).append(r['detected'])
        fam = np.array([r['families'] for r in rk])
        out[k] = {'detected': float(np.mean([r['detected'] for r in rk])),
                  'detected_worst_type': min(by_type, key=lambda t: np.mean(by_type[t])),
                  'detected_worst': float(min(np.mean(v) for v in by_type.values())),
                  'false_alarm': float(np.mean([r['false_alarm'] for r in rk])),
                  'false_alarm_worst_fold': float(max(r['false_alarm'] for r in rk)),
                  'held_out_false_alarm': float(np.mean([r['held_out_false_alarm'] for r in rk])),
                  'families': float(fam.mean()) if fam.size else None,
                  'families_worst': float(fam.mean(axis=0).min()) if fam.size else None}
    return out


def print_summary(title: str, summary: dict, rate: float) -> None:
    print(f'\n{title} (stated false-alarm rate {100 * rate:g} %)')
    print(f"{'images':>6} | {'left-out type flagged':>24} | {'known new samples flagged':>27} |"
          f" {'families flagged':>18}")
    for k, s in summary.items():
        fam = ('-' if s['families'] is None else
               f"{100 * s['families']:5.1f} % (min {100 * s['families_worst']:.0f})")
        worst = s['detected_worst_type'] if s['detected_worst'] < 1 else 'type'
        print(f"{k:>6} | {100 * s['detected']:6.1f} % (worst {worst} "
              f"{100 * s['detected_worst']:.0f}) | {100 * s['false_alarm']:5.1f} % "
              f"(worst fold {100 * s['false_alarm_worst_fold']:4.1f}) | {fam:>18}")


# ---- the alternatives (--compare) ------------------------------------------------------------
class _Mahalanobis:
    def fit(self, X, y):
        from mux_classifier.novelty import fit_class_distance
        self.core = fit_class_distance(X, y, 16)
        return self

    def score(self, X):
        from mux_classifier.novelty import class_distance
        return class_distance(self.core, X)


class _Whitened:
    """Standardised, projected on 32 principal components, whitened."""

    def _fit_projection(self, X):
        from mux_classifier.features import column_scaling
        self.mean, self.scale = column_scaling(X)
        Z = (X - self.mean) / self.scale
        _, s, Vt = np.linalg.svd(Z, full_matrices=False)
        r = min(32, int((s > s[0] * 1e-9).sum()))
        self.V = Vt[:r] / s[:r, None] * np.sqrt(len(Z))
        return Z @ self.V.T

    def _project(self, X):
        return ((X - self.mean) / self.scale) @ self.V.T


class _Knn(_Whitened):
    def fit(self, X, y):
        from sklearn.neighbors import NearestNeighbors
        self.nn = NearestNeighbors(n_neighbors=5).fit(self._fit_projection(X))
        return self

    def score(self, X):
        return self.nn.kneighbors(self._project(X))[0][:, -1]


class _Forest(_Whitened):
    def fit(self, X, y):
        from sklearn.ensemble import IsolationForest
        self.f = IsolationForest(n_estimators=200, random_state=0).fit(self._fit_projection(X))
        return self

    def score(self, X):
        return -self.f.score_samples(self._project(X))


class _OneClassSvm(_Whitened):
    def __init__(self, rate):
        self.rate = rate

    def fit(self, X, y):
        from sklearn.svm import OneClassSVM
        self.f = OneClassSVM(nu=self.rate, gamma='scale').fit(self._fit_projection(X))
        return self

    def score(self, X):
        return -self.f.decision_function(self._project(X))


def compare(seed: int, work: Path, family_seeds, args, patterns) -> list[dict]:
    """The alternatives at the full image count, holding out physical sample 0 of the known
    classes; every score thresholded at the (1 - rate) quantile of its held-out groups."""
    from lightstage_physics.scene_models import object_type_of
    from mux_trainer.novelty_fit import NOVELTY_STREAM, sample_groups
    from sklearn.model_selection import GroupKFold

    data = _data(work / f'capture_{seed}')
    types = np.array([object_type_of(c) for c in data.class_names])[data.labels]
    groups = sample_groups(data)
    fam_data = [_data(work / f'family_{f}') for f in family_seeds]
    scorers = {'mahalanobis (this)': _Mahalanobis, 'kNN distance (k=5)': _Knn,
               'isolation forest': _Forest,
               'one-class SVM': lambda: _OneClassSvm(args.false_alarm_rate)}
    out = []
    for features in ('intensity_stats', 'hog_grid'):
        train = np.stack(_features(data, patterns, args.train_renders, seed, NOVELTY_STREAM,
                                   features))
        test = np.stack(_features(data, patterns, args.test_renders, seed, TEST_STREAM,
                                  features))
        fams = [np.vstack(_features(d, patterns, args.test_renders, seed, TEST_STREAM,
                                    features)) for d in fam_data]
        for name, make in scorers.items():
            t0 = time.perf_counter()
            det, fa, fam = [], [], []
            for left_out in dict.fromkeys(types.tolist()):
                fit = (types != left_out) & (data.instance != 0)
                known = (types != left_out) & (data.instance == 0)
                X = train[:, fit].reshape(-1, train.shape[2])
                y = np.tile(data.labels[fit], len(train))
                g = np.tile(groups[fit], len(train))
                held = np.empty(len(X))
                for tr, te in GroupKFold(5).split(X, y, g):
                    held[te] = make().fit(X[tr], y[tr]).score(X[te])
                threshold = np.quantile(held, 1 - args.false_alarm_rate)
                model = make().fit(X, y)

                def flagged(Z):
                    return float((model.score(Z.reshape(-1, Z.shape[-1])) >= threshold).mean())
                det.append(flagged(test[:, types == left_out]))
                fa.append(flagged(test[:, known]))
                fam.append(np.mean([flagged(f) for f in fams]) if fams else np.nan)
            row = {'seed': seed, 'features': features, 'score': name,
                   'detected': float(np.mean(det)), 'detected_worst': float(min(det)),
                   'false_alarm': float(np.mean(fa)), 'families': float(np.mean(fam)),
                   'seconds': time.perf_counter() - t0}
            out.append(row)
            print(f"{features:>15} | {name:>19} | left-out type {100 * row['detected']:5.1f} % "
                  f"(worst {100 * row['detected_worst']:3.0f}) | known {100 * row['false_alarm']:4.1f} %"
                  f" | families {100 * row['families']:5.1f} %", flush=True)
    return out


def main(argv=None) -> int:
    from mux_trainer.snr_optimal import s_matrix_for_sites
    args = parse_args(argv)
    tune, report, families = _ints(args.tune_seeds), _ints(args.report_seeds), _ints(args.families)
    patterns = s_matrix_for_sites(8)[:, :args.columns]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix='novelty-') as tmp:
        work = Path(args.work_dir) if args.work_dir else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        make_inputs(work, tune + report, families, args)
        print(f'inputs: {time.perf_counter() - t0:.0f} s ({work})', flush=True)
        results = {'args': vars(args), 'seeds': {}}
        for label, seeds in (('tune', tune), ('report', report)):
            rows = []
            for seed in seeds:
                rows += measure(seed, work, families, args, patterns)['rows']
            if rows:
                results['seeds'][label] = {'seeds': seeds, 'rows': rows,
                                           'summary': summarise(rows)}
                print_summary(f'{label} seeds {seeds}: each type left out in turn, '
                              f'{args.samples} held-out sample folds',
                              results['seeds'][label]['summary'], args.false_alarm_rate)
        if args.compare:
            print(f'\nalternatives at {4 * args.columns} images, tune seeds {tune}, physical '
                  'sample 0 held out, plain held-out quantile for every score:')
            results['compare'] = [r for seed in tune
                                  for r in compare(seed, work, families, args, patterns)]
    print(f'\ntotal {time.perf_counter() - t0:.0f} s')
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
