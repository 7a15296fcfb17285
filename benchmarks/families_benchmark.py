"""Every method on many procedural object families, scored on physical samples never seen in
training (naive, SNR-optimal, greedy, learned at 4 and 8 exposures).

For each family seed (`lightstage_physics.families`: one shape, two class materials that
differ in 1-3 optical properties scaled by --strength, --samples physical samples per class
with their own variation, --poses free placements each), the capture is rendered at --size
px (cached under --cache) and loaded at its size with Sigma3 noise and `--features`. Folds
hold out physical samples: fold f holds out sample number f of every class with all its
poses (the grouping of `holdout.holdout_split(..., instance=...)`, one group per fold instead
of a random subset), so with --folds equal to --samples every sample is held out once. Each
method is trained on the rest (its own inner splits as `SplitScoring.inner_groups` /
the learned method's `inner_groups` make them: --inner-groups auto, the product's default,
holds out whole training samples, every one in turn; poses holds out pose numbers, the
paper's rule) and scored on the held-out
samples with `holdout.evaluate_heldout` / `learned.evaluate_learned_heldout` (fresh noise,
--n-renders draws):
- naive: `NaiveClassifier` (all LEDs on, one image; the same figure at 4 and 8 exposures);
- snr_optimal: `SnrOptimalClassifier(n_images=2)`, its first 1 / 2 columns per colour;
- greedy: `GreedyPatternSelector(mode='per_colour', n_patterns=2)`, 1 / 2 columns;
- learned: `LearnedIlluminationClassifier(n_images=4)` and `(n_images=8)`, its defaults, with
  this fold's greedy columns as its greedy start (the same search, not run twice).
The inner estimate of a method is its own figure for the kept light (`inner_estimate_` /
`estimate_by_images_`: the baselines' split accuracy; greedy's, and learned's chosen
candidate's, less the optimism of having chosen it on those splits
(`mux_trainer.selection_bias`)) and says how its splits were made; the split accuracy
itself is kept in the results file as `search4` / `search8`.

Prints per family (fold means) and per method: the mean and the worst family at 4 and 8
exposures, the mean inner-minus-held-out gap, the share of families where learned is
behind greedy or SNR-optimal, and its lead over each family's better rival with how much of
that lead's spread is the family's own samples (`lead_spread`). Per-family results are
appended to --results (JSON lines) as they finish, and a rerun with the same file skips the
families it holds.

    .venv/bin/python benchmarks/families_benchmark.py --seeds 100-159 --strength 0.5
    .venv/bin/python benchmarks/families_benchmark.py --quick
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from lightstage_physics.capture_format import load_capture
from lightstage_physics.families import draw_family, generate_family
from lightstage_physics.rig import site_to_led_patterns
from mux_classifier.hog import HogConfig
from mux_trainer.baselines import NaiveClassifier, SnrOptimalClassifier
from mux_trainer.data import search_data
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.holdout import evaluate_heldout
from mux_trainer.learned import LearnedIlluminationClassifier, Starts, evaluate_learned_heldout
from mux_trainer.search_params import SplitScoring

METHODS = ('naive', 'snr_optimal', 'greedy', 'learned')
EXPOSURES = (4, 8)


def parse_seeds(text: str) -> list[int]:
    """'100-119' or '1,5,9' or '0-3,10'."""
    seeds = []
    for part in text.split(','):
        if '-' in part.strip()[1:]:
            lo, hi = part.split('-', 1)
            seeds.extend(range(int(lo), int(hi) + 1))
        elif part.strip():
            seeds.append(int(part))
    return seeds


def family_capture(args, seed: int) -> Path:
    """The family's capture folder under --cache (rendered once per setting)."""
    name = (f'st{args.strength:g}_n{args.samples}_p{args.poses}_px{args.size}'
            f'_sp{args.sample_spread:g}')
    path = Path(args.cache) / name / f'family{seed}'
    done = path / '.complete'
    if not done.exists():
        generate_family(path, seed, args.strength, args.samples, args.poses, args.size,
                        sample_spread=args.sample_spread, n_jobs=1, overwrite=True)
        done.touch()
    return path


def run_fold(train, test, args) -> dict:
    """{method: {'4': held-out, '8': held-out, 'inner4', 'inner8', 'seconds'}} of one fold."""
    scoring = SplitScoring(n_repeats=args.n_repeats, inner_groups=args.inner_groups)
    out = {}
    t0 = time.perf_counter()
    greedy_columns = None
    for name in ('naive', 'snr_optimal', 'greedy'):
        if name not in args.methods and not (name == 'greedy' and 'learned' in args.methods):
            continue
        t0 = time.perf_counter()
        if name == 'naive':
            model = NaiveClassifier(scoring=scoring, seed=args.seed)
        elif name == 'snr_optimal':
            model = SnrOptimalClassifier(n_images=2, scoring=scoring, seed=args.seed)
        else:
            model = GreedyPatternSelector(mode='per_colour', n_patterns=2, scoring=scoring,
                                          seed=args.seed)
        model.fit(train)
        seconds = time.perf_counter() - t0
        held = evaluate_heldout(model, test, args.n_renders, args.seed)['accuracy_by_images']
        inner = model.estimate_by_images_
        cols = {4: 1, 8: 1} if name == 'naive' else {4: 1, 8: 2}
        out[name] = {**{str(e): float(held[c]) for e, c in cols.items()},
                     **{f'inner{e}': float(inner[c]) for e, c in cols.items()},
                     **{f'search{e}': float(model.accuracy_by_images_[c])
                        for e, c in cols.items()},
                     'seconds': seconds, 'inner_held_out': model.inner_estimate_['held_out']}
        if name == 'greedy':
            greedy_columns = model.patterns_
    if 'learned' in args.methods:
        res = {'seconds': 0.0}
        for e in EXPOSURES:
            starts = {}
            builtin = list(Starts().names)
            if greedy_columns is not None:
                builtin.remove('greedy')
                starts['greedy'] = site_to_led_patterns(greedy_columns[:, :e // 4],
                                                        train.n_channels)
            model = LearnedIlluminationClassifier(
                n_images=e, seed=args.seed, starts=Starts(names=tuple(builtin), patterns=starts),
                scoring=SplitScoring(n_repeats=args.n_repeats,
                                     inner_groups=args.inner_groups)).fit(train)
            res[str(e)] = evaluate_learned_heldout(model, test, args.n_renders,
                                                   args.seed)['accuracy']
            res[f'inner{e}'] = float(model.estimate_by_images_[e])
            res[f'search{e}'] = float(model.accuracy_by_images_[e])
            res[f'chosen{e}'] = model.chosen_
            res['seconds'] += model.train_seconds_
            res['inner_held_out'] = model.inner_estimate_['held_out']
        out['learned'] = res
    if 'greedy' not in args.methods:
        out.pop('greedy', None)
    return out


def family_data(path, features: str, size: int):
    """A family's capture as the methods see it: Sigma3 noise, `features`, at its size."""
    return search_data(load_capture(path), 'sigma3', features=features,
                       hog_config=HogConfig(image_size=size, cell_px=max(1, size // 10),
                                            block_cells=10))


def sample_folds(data, folds):
    """(train, test) per fold: fold f holds out physical sample f of every class."""
    for f in folds:
        held = data.instance == f
        yield data.subset(np.flatnonzero(~held)), data.subset(np.flatnonzero(held))


def run_family(seed: int, args) -> dict:
    t0 = time.perf_counter()
    path = family_capture(args, seed)
    render_s = time.perf_counter() - t0
    data = family_data(path, args.features, args.size)
    folds = sorted(np.unique(data.instance))[:args.folds]
    per_fold = [run_fold(train, test, args) for train, test in sample_folds(data, folds)]
    family = draw_family(seed)
    row = {'seed': seed, 'kind': family.kind, 'cues': list(family.cues), 'folds': len(folds),
           'render_seconds': render_s, 'seconds': time.perf_counter() - t0, 'methods': {}}
    for name in per_fold[0]:
        keys = [k for k in per_fold[0][name] if not k.startswith(('chosen', 'inner_held'))]
        row['methods'][name] = {k: float(np.mean([p[name][k] for p in per_fold])) for k in keys}
        row['methods'][name]['inner_held_out'] = sorted({p[name]['inner_held_out']
                                                         for p in per_fold})
        row['methods'][name]['by_fold'] = [{k: p[name][k] for k in ('4', '8')} for p in per_fold]
        if name == 'learned':
            row['methods'][name]['chosen'] = [[p[name][f'chosen{e}'] for e in EXPOSURES]
                                              for p in per_fold]
    return row


def settings(args) -> dict:
    keys = ('strength', 'samples', 'poses', 'size', 'sample_spread', 'features', 'n_repeats',
            'n_renders', 'folds', 'inner_groups', 'seed')
    return {k: getattr(args, k) for k in keys}


def standard_error(x) -> float:
    """The standard error of the mean over the families (nan for one family): what a mean
    over this many families can tell apart."""
    x = np.asarray(x, dtype=np.float64)
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float('nan')


def lead_spread(rows: list[dict], rivals, e: str) -> str:
    """Learned's lead over each family's better rival (by the family's fold mean): its mean
    and spread over the families, and how much of that spread is the family's own samples:
    the standard deviation of the per-fold leads between a family's folds (root mean square
    over the families) and so the noise of a family's fold mean."""
    folds = {len(r['methods']['learned']['by_fold']) for r in rows}
    best = [max(rivals, key=lambda m: r['methods'][m][e]) for r in rows]
    lead = 100 * np.array([r['methods']['learned'][e] - r['methods'][b][e]
                           for r, b in zip(rows, best)])
    text = (f'learned - the better rival of each family: mean {lead.mean():+.1f} points, '
            f'standard deviation {np.std(lead, ddof=1) if lead.size > 1 else np.nan:.1f} over '
            'the families')
    if len(folds) != 1 or min(folds) < 2:
        return text
    n = folds.pop()
    per_fold = 100 * np.array([[f[e] - g[e] for f, g in
                                zip(r['methods']['learned']['by_fold'], r['methods'][b]['by_fold'])]
                               for r, b in zip(rows, best)])
    between = float(np.sqrt(np.mean(np.var(per_fold, axis=1, ddof=1))))
    return (f'{text}; between a family\'s {n} folds {between:.1f} (root mean square), so about '
            f'{between / np.sqrt(n):.1f} of noise in a family\'s fold mean')


def summarise(rows: list[dict], methods) -> str:
    lines = []
    head = f'{"seed":>5} {"kind":12s} {"cues":22s}' + ''.join(
        f' {m[:11]:>11s}' for m in methods)
    lines.append('per family: held-out accuracy % at 4 / 8 exposures (fold means)')
    lines.append(head)
    for r in rows:
        cells = ''.join(f' {100 * r["methods"][m]["4"]:5.1f}/{100 * r["methods"][m]["8"]:5.1f}'
                        for m in methods)
        lines.append(f'{r["seed"]:>5} {r["kind"]:12s} {",".join(r["cues"]):22s}{cells}')
    lines.append('')
    lines.append(f'over {len(rows)} families: held-out % (mean, worst family), inner estimate '
                 '% and the gap inner - held-out (points: mean, its standard error over the '
                 'families, and the mean of its size per family)')
    held = sorted({h for r in rows for m in methods
                   for h in r['methods'][m].get('inner_held_out', [])})
    lines.append(f'(the inner splits held out: {", ".join(held) or "?"})')
    lines.append(f'{"method":12s} {"mean 4":>7s} {"mean 8":>7s} {"worst 4":>8s} {"worst 8":>8s}'
                 f' {"inner 4":>8s} {"inner 8":>8s} {"gap 4":>6s} {"gap 8":>6s}'
                 f' {"se 4":>5s} {"se 8":>5s} {"|gap| 4":>8s} {"|gap| 8":>8s}')
    for m in methods:
        a4 = np.array([r['methods'][m]['4'] for r in rows]) * 100
        a8 = np.array([r['methods'][m]['8'] for r in rows]) * 100
        i4 = np.array([r['methods'][m]['inner4'] for r in rows]) * 100
        i8 = np.array([r['methods'][m]['inner8'] for r in rows]) * 100
        lines.append(f'{m:12s} {a4.mean():7.1f} {a8.mean():7.1f} {a4.min():8.1f} {a8.min():8.1f}'
                     f' {i4.mean():8.1f} {i8.mean():8.1f} {(i4 - a4).mean():+6.1f}'
                     f' {(i8 - a8).mean():+6.1f} {standard_error(i4 - a4):5.1f}'
                     f' {standard_error(i8 - a8):5.1f} {np.abs(i4 - a4).mean():8.1f}'
                     f' {np.abs(i8 - a8).mean():8.1f}')
    if 'learned' in methods:
        lines.append('')
        for e in ('4', '8'):
            learned = np.array([r['methods']['learned'][e] for r in rows])
            for other in ('greedy', 'snr_optimal', 'naive'):
                if other not in methods:
                    continue
                o = np.array([r['methods'][other][e] for r in rows])
                d = 100 * (learned - o)
                lines.append(f'{e} exposures: learned - {other}: mean {d.mean():+.1f} points '
                             f'(standard error {standard_error(d):.1f}), behind in '
                             f'{np.mean(learned < o - 1e-9):.0%} of families')
            rivals = [m for m in ('greedy', 'snr_optimal') if m in methods]
            if rivals:
                best = np.max([[r['methods'][m][e] for m in rivals] for r in rows], axis=1)
                lines.append(f'{e} exposures: learned behind greedy or SNR-optimal in '
                             f'{np.mean(learned < best - 1e-9):.0%} of families, by more than '
                             f'5 points in {np.mean(learned < best - 0.05):.0%}')
                lines.append(f'{e} exposures: {lead_spread(rows, rivals, e)}')
    multiplexed = [m for m in ('snr_optimal', 'greedy', 'learned') if m in methods]
    if 'naive' in methods and multiplexed:
        best_m = max(multiplexed, key=lambda m: np.mean([r['methods'][m]['4'] for r in rows]))
        gain = np.mean([r['methods'][best_m]['4'] - r['methods']['naive']['4'] for r in rows])
        lines.append(f'best multiplexed method at 4 exposures: {best_m}, '
                     f'{100 * gain:+.1f} points over naive')
    return '\n'.join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split('\n\n', 1)[1])
    p.add_argument('--seeds', default='100-159', type=parse_seeds,
                   help="family seeds: '100-159', '1,5,9' (default 100-159, the report seeds)")
    p.add_argument('--strength', type=float, default=0.5,
                   help='scale of the difference between the classes (0 = the chance control)')
    p.add_argument('--samples', type=int, default=4, help='physical samples per class (default 4)')
    p.add_argument('--poses', type=int, default=4, help='free placements per sample (default 4)')
    p.add_argument('--size', type=int, default=60,
                   help='image side in px, rendered and classified (default 60)')
    p.add_argument('--sample-spread', type=float, default=0.05,
                   help='material spread between samples of a class (default 0.05)')
    p.add_argument('--features', default='intensity_stats')
    p.add_argument('--folds', type=int, default=None,
                   help='folds (fold f holds out sample f of every class; default: --samples, '
                        'every sample held out once)')
    p.add_argument('--inner-groups', default='auto', choices=('auto', 'poses', 'instances'),
                   help="what the methods' inner splits hold out on the training part: auto "
                        "(the product's default: physical samples where every class has two "
                        "or more), poses (pose numbers, the paper's rule) or instances")
    p.add_argument('--n-repeats', type=int, default=100,
                   help="inner splits of greedy, SNR-optimal, naive and learned (default 100)")
    p.add_argument('--n-renders', type=int, default=4, help='noise draws of the test images')
    p.add_argument('--methods', default=','.join(METHODS), type=lambda v: v.split(','))
    p.add_argument('--seed', type=int, default=0, help="the methods' seed")
    p.add_argument('--cache', default='out/families_cache', help='where the captures go')
    p.add_argument('--results', help='JSON lines file: one line per family, appended as they '
                                     'finish; families already there are skipped')
    p.add_argument('--summary-only', action='store_true',
                   help='print the summary of the families --results holds for these settings '
                        'and seeds; run nothing (e.g. after workers on parts of the seeds wrote '
                        'files that were concatenated)')
    p.add_argument('--quick', action='store_true',
                   help='a small run of the same measurement, as `make bench` runs it: 1 family, '
                        '2 folds, 20 inner splits, 2 poses per sample')
    args = p.parse_args(argv)
    if args.quick:
        args.seeds, args.folds, args.n_repeats, args.poses = args.seeds[:1], 2, 20, 2
    args.folds = args.samples if args.folds is None else args.folds
    unknown = set(args.methods) - set(METHODS)
    if unknown:
        p.error(f'unknown method(s) {sorted(unknown)}; choose from {", ".join(METHODS)}')
    if not 1 <= args.folds <= args.samples or args.samples < 2:
        p.error('need --samples >= 2 and 1 <= --folds <= --samples')
    rows, done = [], set()
    if args.results and Path(args.results).exists():
        for line in Path(args.results).read_text().splitlines():
            row = json.loads(line)
            if row.get('settings') == settings(args) and row['seed'] in args.seeds:
                rows.append(row)
                done.add(row['seed'])
    if args.summary_only and not rows:
        p.error('--summary-only: --results holds no family for these settings and seeds')
    for seed in args.seeds:
        if seed in done or args.summary_only:
            continue
        row = run_family(seed, args)
        row['settings'] = settings(args)
        rows.append(row)
        m = row['methods']
        print(f'family {seed} ({row["kind"]}, {",".join(row["cues"])}): ' + ', '.join(
            f'{k} {100 * v["4"]:.1f}/{100 * v["8"]:.1f} (inner {100 * v["inner4"]:.1f}/'
            f'{100 * v["inner8"]:.1f})' for k, v in m.items())
              + f'  [{row["seconds"]:.0f} s]', flush=True)
        if args.results:
            with open(args.results, 'a') as f:
                f.write(json.dumps(row) + '\n')
    rows.sort(key=lambda r: args.seeds.index(r['seed']))
    print()
    print('settings: ' + ', '.join(f'{k}={v}' for k, v in settings(args).items())
          + f'; seeds {args.seeds[0]}..{args.seeds[-1]}: {len(rows)} families '
          f'({", ".join(str(r["seed"]) for r in rows)})')
    print(summarise(rows, [m for m in METHODS if m in args.methods]))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
