"""The evaluation that regenerates the paper's Table 1 and accuracy-vs-image-count figure.

`run_evaluation(modelset, ...)` for each noise setting: hold out a random quarter of the
pose indices, train every requested method on the rest (greedy per-colour search to a
fixed column count as the paper does for its figures, SNR-optimal with a classifier per
column count, naive all-LEDs-on with and without a bag of words, optionally the joint
32-LED greedy search), and test them on fresh noisy renders of the held-out poses.
With several feature extractors (`features`), every method runs once per extractor (the
naive + BoW baseline, which has its own features, once): the document's `methods` and
`by_noise` are the first extractor's, `by_features[name]` holds each one's.
`write_outputs` writes results.json, table1.csv, accuracy_vs_images.csv and the PNG plots
(the first extractor's), and table1_features.csv with every extractor's Table 1.
"""
from __future__ import annotations

import csv
import json
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np
from lightstage_physics.workers import check_jobs

from .baselines import NaiveClassifier, SnrOptimalClassifier
from .data import search_data
from .greedy import GreedyPatternSelector
from .holdout import HOLDOUT_BY, accuracy_by_type, holdout_split, method_summary
from .search_params import Execution, SplitScoring

METHODS = ('naive', 'naive_bow', 'snr_optimal', 'greedy', 'greedy_joint', 'learned')
DEFAULT_METHODS = ('naive', 'naive_bow', 'snr_optimal', 'greedy')


def _log(msg: str, quiet: bool) -> None:
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def _naive_bow_summary(naive, train_data, test_data, n_renders, seed, n_jobs):
    """Naive illumination, bag of visual words on dense HOG patches, linear SVM."""
    from .bow_baseline import NaiveBowClassifier
    t0 = time.perf_counter()
    model = NaiveBowClassifier(seed=seed).fit_from_naive(naive, train_data)
    train_s = time.perf_counter() - t0
    correct = np.zeros(test_data.n_samples)
    for r in range(int(n_renders)):
        correct += model.predict_test(test_data, r, seed) == test_data.labels
    correct /= n_renders
    acc = float(correct.mean())
    return {
        'accuracy': acc, 'n_images': 1, 'images_per_pattern': 1, 'n_exposures': 1,
        'accuracy_by_type': accuracy_by_type(test_data, correct),
        'accuracy_by_images': {'1': acc}, 'mode': 'naive', 'features': 'bow_dense_hog',
        'patterns': np.asarray(naive.patterns_).astype(int).tolist(),
        'train_seconds': float(train_s), 'n_words': model.n_words_,
    }


def _learned_result(train, test, noise, *, n_renders, seed, hog_config, quiet, progress,
                    n_repeats=400, exposures=None, steps=None, binary=False,
                    inner_groups='auto') -> dict:
    """Learned illumination: one model per exposure count (`learned_method`), trained on
    `train` (chosen by the inner splits within it, n_repeats of them, by physical sample or
    pose as `inner_groups` says, as every method's), tested like every method."""
    import contextlib

    from .learned_method import build_learned, learned_summary
    from .learned_schedule import EVAL_EXPOSURES
    models = {}
    t0 = time.perf_counter()
    for k in exposures or EVAL_EXPOSURES:
        _log(f'[{noise}] learned: training {k} exposures on {train.n_samples} samples', quiet)
        model = build_learned(k, binary=binary, steps=steps, noise=noise,
                              hog_config=hog_config, seed=seed, progress=progress,
                              n_repeats=n_repeats, inner_groups=inner_groups)
        with contextlib.redirect_stdout(sys.stderr):  # stdout: only the results (--json)
            models[int(k)] = model.fit(train)
    return learned_summary(models, test, n_renders, seed, train_seconds=time.perf_counter() - t0)


def evaluate_noise_setting(modelset, noise: str, methods=DEFAULT_METHODS, *, n_repeats=400,
                           max_images=8, holdout_fraction=0.25, n_renders=4, seed=0,
                           n_jobs=1, hog_config=None, beam_width=1, joint_max_images=None,
                           quiet=False, progress=False, features='hog_grid',
                           naive_bow=None, holdout_by='poses', count_rule='max',
                           learned=None, learned_options=None, inner_groups='auto',
                           answers=True) -> dict:
    """All requested methods at one noise setting; returns {'methods': {...}, ...}.

    joint_max_images: pattern columns of 'greedy_joint' (one exposure each; default
    max_images). 4 x max_images gives it the exposures of the per-colour search.
    features: the extractor every method (but naive + BoW) scores and classifies with.
    naive_bow: an earlier run's naive + BoW result for this noise, reused instead of
    training it again (it does not depend on `features`).
    holdout_by: 'poses' (the paper's rule: pose indices held out, their objects seen in
    other poses) or 'instances' (physical samples held out with all their poses).
    inner_groups: what every method's inner splits hold out on the training part
    (`search_params.SplitScoring`: 'auto', physical samples where it has two or more of
    every class, else poses).
    count_rule: how each method's column count is chosen from its split accuracies
    (`column_count`); every method's result also reports what each rule would keep.
    learned: an earlier run's 'learned' result for this noise, reused (it classifies with
    its own statistics, whatever `features`); learned_options: `_learned_result`'s.
    answers: also calibrate every pattern method as `lightstage train` does and report its
    answers on the held-out samples (`answers_summary`: anytime against the fixed count,
    calibration error and reliability, accuracy against coverage, unknown objects).
    """
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise ValueError(f'unknown methods {sorted(unknown)}; choose from {", ".join(METHODS)}')
    check_jobs(n_jobs)
    if holdout_by not in HOLDOUT_BY:
        raise ValueError(f'unknown holdout_by {holdout_by!r}; choose from {", ".join(HOLDOUT_BY)}')
    data = search_data(modelset, noise, hog_config=hog_config, features=features)
    instance = np.asarray(modelset.instance) if holdout_by == 'instances' else None
    train_idx, test_idx = holdout_split(data, holdout_fraction, seed, instance)
    train, test = data.subset(train_idx), data.subset(test_idx)
    common = dict(scoring=SplitScoring(n_repeats=n_repeats, inner_groups=inner_groups), seed=seed,
                  execution=Execution(n_jobs=n_jobs, progress=progress), count_rule=count_rule)
    results: dict = {}
    models: dict = {}
    naive = None
    for name in methods:
        t0 = time.perf_counter()
        if name == 'naive_bow' and naive_bow is not None:
            results[name] = naive_bow
            continue
        if name == 'learned':
            results[name] = learned or _learned_result(
                train, test, noise, n_renders=n_renders, seed=seed, hog_config=hog_config,
                quiet=quiet, progress=progress, n_repeats=n_repeats, inner_groups=inner_groups,
                **(learned_options or {}))
            _log(f'[{noise}] learned: held-out accuracy {results[name]["accuracy"]:.4f} at '
                 f'{results[name]["n_exposures"]} exposure(s)', quiet)
            continue
        _log(f'[{noise}, {features}] {name}: training on {train.n_samples} samples '
             f'({len(np.unique(train.pose_index))} poses per class)', quiet)
        if name in ('naive', 'naive_bow'):
            if naive is None:
                naive = NaiveClassifier(**common).fit(train)
            model = naive
        elif name == 'snr_optimal':
            model = SnrOptimalClassifier(n_images=max_images, **common).fit(train)
        elif name == 'greedy':
            model = GreedyPatternSelector(mode='per_colour', n_patterns=max_images,
                                          **common).fit(train)
        else:  # greedy_joint
            model = GreedyPatternSelector(mode='joint', n_patterns=joint_max_images or max_images,
                                          beam_width=beam_width, **common).fit(train)
        train_s = time.perf_counter() - t0
        if name == 'naive_bow':
            results[name] = _naive_bow_summary(naive, train, test, n_renders, seed, n_jobs)
        else:
            results[name] = method_summary(model, test, n_renders, seed, train_seconds=train_s)
            models[name] = model
            if answers:
                results[name]['answers'] = answers_summary(model, train, test, n_renders, seed)
        _log(f'[{noise}, {results[name]["features"]}] {name}: held-out accuracy '
             f'{results[name]["accuracy"]:.4f} at {results[name]["n_exposures"]} exposure(s) '
             f'({time.perf_counter() - t0:.1f} s)', quiet)
    return {'noise': noise, 'features': features,
            'n_train': int(train.n_samples), 'n_test': int(test.n_samples),
            'test_poses': sorted(int(p) for p in np.unique(test.pose_index)),
            'holdout_by': holdout_by,
            'test_instances': (sorted(int(i) for i in np.unique(instance[test_idx]))
                               if instance is not None else None),
            'methods': results, '_models': models}


def answers_summary(model, train, test, n_renders: int = 4, seed: int = 0) -> dict:
    """What a user of a fitted pattern model gets on held-out samples, calibrated as
    `lightstage train` calibrates it: the anytime rule against the fixed count, the
    calibration error with its reliability bins, accuracy against coverage
    (`calibration.evaluate_anytime`), and unknown objects (`novelty_fit.evaluate_unknown`)."""
    from .calibration import calibrate_pattern_model, evaluate_anytime
    from .novelty_fit import evaluate_unknown
    confidence = calibrate_pattern_model(model)
    out = evaluate_anytime(model, confidence, test, n_renders, seed)
    out['inner'] = confidence.estimate
    out['unknown'] = evaluate_unknown(model, train, test, n_renders, seed)
    return out


def run_evaluation(modelset, noises=('sigma3',), methods=DEFAULT_METHODS,
                   features=('hog_grid',), **kwargs) -> dict:
    """Every noise setting for every feature extractor; the top-level 'methods' are those of
    the first setting and the first extractor, 'by_noise' the first extractor's, and
    'by_features[name]' = {'methods' (first noise), 'by_noise'} for each extractor."""
    features = list(features)
    if not features:
        raise ValueError('no feature extractor given')
    by_features = {}
    for feature in features:
        by_noise = {}
        for noise in noises:
            earlier = by_features[features[0]]['by_noise'][noise] if by_features else None
            bow = earlier['methods'].get('naive_bow') if earlier else None
            learned = earlier['methods'].get('learned') if earlier else None
            by_noise[noise] = evaluate_noise_setting(modelset, noise, methods, features=feature,
                                                     naive_bow=bow, learned=learned, **kwargs)
        by_features[feature] = {'methods': by_noise[noises[0]]['methods'], 'by_noise': by_noise}
    first = by_features[features[0]]
    return {'noise': noises[0], 'features': features[0], 'methods': first['methods'],
            'by_noise': first['by_noise'], 'by_features': by_features,
            'object_types': modelset.object_types,
            'class_names': list(modelset.class_names)}


def _without_models(by_noise: dict) -> dict:
    return {n: {k: v for k, v in r.items() if k != '_models'} for n, r in by_noise.items()}


def json_ready(results: dict) -> dict:
    """Drop the fitted models (kept for plots) from a result document."""
    out = {k: v for k, v in results.items() if k not in ('by_noise', 'by_features')}
    out['by_noise'] = _without_models(results['by_noise'])
    if 'by_features' in results:  # absent from a results.json written before it existed
        out['by_features'] = {f: {'methods': r['methods'], 'by_noise': _without_models(r['by_noise'])}
                              for f, r in results['by_features'].items()}
    return out


RESULTS_FILE = 'results.json'


def check_output_dir(out_dir) -> Path:
    """Refuse, before an evaluation, an output folder that cannot take its files: a regular
    file, a path under one, a folder this user cannot create files in (checked by creating
    one). Raises ValueError naming the folder and what to do."""
    from lightstage_physics.errors import DestinationError
    from lightstage_physics.output_files import check_output_file
    try:
        return check_output_file(Path(out_dir) / RESULTS_FILE, overwrite=True).parent
    except DestinationError as exc:
        raise ValueError(f'cannot write the results into {out_dir}: {exc}') from None


def keep_outputs(doc: dict, out_dir, error: Exception) -> str:
    """Keep a JSON-ready result document whose outputs could not be written into `out_dir`
    in a rescue folder; returns the message saying where (or that it could not be kept)."""
    from lightstage_physics.output_files import save_in_rescue_dir
    failed = f'could not write the results into {out_dir} ({getattr(error, "strerror", None) or error})'
    name = f'eval-{time.strftime("%Y%m%d-%H%M%S")}.{os.getpid()}.{RESULTS_FILE}'
    try:
        kept = save_in_rescue_dir(name, lambda path: path.write_text(json.dumps(doc, indent=2)))
    except OSError as exc:
        return (f'{failed}, nor in a rescue folder ({exc}); the results printed above are all '
                'that is left of this run')
    return (f'{failed}; the results are printed above and kept in {kept}: once the folder '
            f'takes files, write the tables and plots from them with `lightstage eval '
            f'--from-results {shlex.quote(str(kept))} --out {shlex.quote(str(out_dir))}`, no '
            'need to evaluate again')


def write_outputs(results: dict, out_dir, plots: bool = True) -> list[Path]:
    """results.json, table1.csv, accuracy_vs_images.csv, answers.csv (when the methods were
    calibrated) and (plots) PNG figures. `results`
    is `run_evaluation`'s, or its JSON-ready document (`json_ready`, a results.json)."""
    doc = json_ready(results)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    path = out / RESULTS_FILE
    path.write_text(json.dumps(doc, indent=2, sort_keys=False))
    written.append(path)
    types = results['object_types']
    path = out / 'table1.csv'
    with path.open('w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['noise', 'method', *types, 'overall', 'n_images', 'n_exposures',
                    'train_seconds', 'infer_ms_per_sample'])
        for noise, r in doc['by_noise'].items():
            for name, m in r['methods'].items():
                w.writerow([noise, name, *[f'{100 * m["accuracy_by_type"].get(t, float("nan")):.2f}'
                                           for t in types],
                            f'{100 * m["accuracy"]:.2f}', m['n_images'], m['n_exposures'],
                            f'{m.get("train_seconds", float("nan")):.1f}',
                            f'{m.get("infer_ms_per_sample", float("nan")):.3f}'])
    written.append(path)
    if 'by_features' in doc:
        path = out / 'table1_features.csv'
        with path.open('w', newline='') as fh:
            w = csv.writer(fh)
            w.writerow(['features', 'noise', 'method', *types, 'overall', 'n_images'])
            for feature, f in doc['by_features'].items():
                for noise, r in f['by_noise'].items():
                    for name, m in r['methods'].items():
                        w.writerow([feature, noise, name,
                                    *[f'{100 * m["accuracy_by_type"].get(t, float("nan")):.2f}'
                                      for t in types],
                                    f'{100 * m["accuracy"]:.2f}', m['n_images']])
        written.append(path)
    path = out / 'accuracy_vs_images.csv'
    with path.open('w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['noise', 'method', 'n_images', 'heldout_accuracy', 'search_accuracy'])
        for noise, r in doc['by_noise'].items():
            for name, m in r['methods'].items():
                for k, acc in m['accuracy_by_images'].items():
                    w.writerow([noise, name, k, f'{acc:.4f}',
                                f'{m.get("search_accuracy_by_images", {}).get(k, float("nan")):.4f}'])
    written.append(path)
    answered = {(noise, name): m['answers'] for noise, r in doc['by_noise'].items()
                for name, m in r['methods'].items() if m.get('answers')}
    if answered:
        path = out / 'answers.csv'
        with path.open('w', newline='') as fh:
            w = csv.writer(fh)
            w.writerow(['noise', 'method', 'budget_exposures', 'full_accuracy',
                        'stop_probability', 'anytime_accuracy', 'anytime_mean_exposures',
                        'accepted_share', 'calibration_error_full', 'calibration_error_anytime',
                        'unknown_flagged', 'unknown_flagged_worst', 'unknown_false_alarms'])
            for (noise, name), a in answered.items():
                u = a.get('unknown') or {}
                w.writerow([noise, name, a['budget_images'], f'{a["full_accuracy"]:.4f}',
                            a['stop_probability'], f'{a["anytime_accuracy"]:.4f}',
                            f'{a["anytime_mean_images"]:.2f}', f'{a["accepted_share"]:.4f}',
                            f'{a["full_calibration_error"]:.4f}',
                            f'{a["anytime_calibration_error"]:.4f}',
                            *[('' if u.get(k) is None else f'{u[k]:.4f}')
                              for k in ('flagged', 'flagged_worst', 'false_alarms')]])
        written.append(path)
    if plots:
        from .evaluation_plots import plot_accuracy_vs_images, plot_answers, plot_pattern_matrices
        if answered:
            written.append(plot_answers(doc, out / 'answers.png'))
        written.append(plot_accuracy_vs_images(doc, out / 'accuracy_vs_images.png'))
        written.append(plot_accuracy_vs_images(doc, out / 'accuracy_vs_exposures.png',
                                               by='exposures'))
        written.append(plot_pattern_matrices(doc, out / 'patterns.png'))
    return written
