"""Held-out accuracy against cue strength: learned vs greedy vs SNR-optimal (the plot in docs/LEARNED.md).

For each strength S it makes (once; kept for reuse) the capture `lightstage synth
OUT/weakS --placement free --types coin,note,seal --samples N --poses P --strength S`, then
for each split seed runs `learned_vs_greedy.run_capture` (the same held-out split, test
noise and n_renders for every method) and prints a table of held-out accuracy at 4 and 8
exposures, means over seeds; writes the figures as JSON and the plot as PNG.

    .venv/bin/python benchmarks/learned_strength_sweep.py DIR/sweep \\
        --strengths 0.05,0.1,0.2,0.3,0.5 --seeds 0,1 --png sweep.png
    .venv/bin/python benchmarks/learned_strength_sweep.py --quick   # one strength, one seed, small
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np
from learned_vs_greedy import add_method_arguments, run_capture

from _common import ROOT, parse_args

METHODS = ('greedy', 'snr_optimal', 'learned')


def make_capture(path, strength, args):
    if os.path.exists(os.path.join(path, 'rig.yaml')):
        return
    cmd = [os.path.join(os.path.dirname(sys.executable), 'lightstage'), 'synth', path,
           '--placement', 'free', '--types', args.types, '--samples', str(args.samples),
           '--poses', str(args.poses), '--strength', str(strength), '--jobs', '1', '--quiet']
    subprocess.run(cmd, check=True)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('out', nargs='?', help='folder for the captures (one per strength; default '
                   '.cache/bench_sweep, with --quick .cache/bench_quick_sweep)')
    p.add_argument('--strengths', default='0.05,0.1,0.2,0.3,0.5')
    p.add_argument('--seeds', default='0,1')
    p.add_argument('--types', default='coin,note,seal')
    p.add_argument('--samples', type=int, default=10)
    p.add_argument('--poses', type=int, default=6)
    p.add_argument('--json')
    p.add_argument('--png')
    p.add_argument('--merge', help='comma-separated JSONs this script wrote (e.g. one per split '
                   'seed, run side by side): print their table and plot, run nothing')
    add_method_arguments(p, default_methods=','.join(METHODS))
    args = parse_args(p, argv, strengths='0.5', seeds='0', types='coin,note', samples=2, poses=3,
                      n_repeats=20, exposures=[4])
    args.out = args.out or str(ROOT / '.cache' / ('bench_quick_sweep' if args.quick else 'bench_sweep'))
    args.methods = args.methods.split(',')
    args.learned_starts = args.learned_starts.split(',')
    strengths = [float(s) for s in args.strengths.split(',')]
    seeds = [int(s) for s in args.seeds.split(',')]
    results = {}
    old = json.load(open(args.reuse))['results'] if args.reuse else {}
    if args.merge:
        for path in args.merge.split(','):  # method by method: a file may add one to a split
            for key, split in json.load(open(path))['results'].items():
                results.setdefault(key, {}).update(split)
        strengths = sorted({float(key.split('/')[0]) for key in results})
        seeds = sorted({int(key.split('/')[1]) for key in results})
    for S in ([] if args.merge else strengths):
        path = os.path.join(args.out, f'weak{S:g}')
        make_capture(path, S, args)
        for seed in seeds:
            args.seed = seed
            args.reused = old.get(f'{S:g}/{seed}', {})
            results[f'{S:g}/{seed}'] = run_capture(path, args)
            if args.json:  # after every run: a long sweep keeps what it measured
                with open(args.json, 'w') as f:
                    json.dump({'args': {k: v for k, v in vars(args).items() if k != 'reused'},
                               'results': results}, f, indent=1)
    methods = [m for m in args.methods if m in METHODS or m.startswith('learned')]
    # a split or a method not run (a partial merge) is nan, not an error
    mean = {(S, m, e): float(np.mean([results.get(f'{S:g}/{s}', {}).get(m, {}).get(e, np.nan)
                                      for s in seeds]))
            for S in strengths for m in methods for e in ('4', '8')}
    print('\nheld-out accuracy, mean over seeds ' + ','.join(map(str, seeds)) + ' (4 / 8 exposures)')
    print('strength  ' + '  '.join(f'{m:>15s}' for m in methods))
    for S in strengths:
        print(f'{S:8g}  ' + '  '.join(f'{mean[S, m, "4"]:6.3f} / {mean[S, m, "8"]:5.3f}'
                                      for m in methods))
    print('\nper split: ' + ', '.join(methods) + ' (4 / 8 exposures)')
    # each learned variant (learned, learned_binary) ahead of every method that is not one
    learned = [m for m in methods if m.startswith('learned')]
    baselines = [m for m in methods if not m.startswith('learned')]
    ahead = {(v, e): [0, 0] for v in learned for e in ('4', '8')}  # splits won, counted
    for key in sorted(results, key=lambda k: (float(k.split('/')[0]), int(k.split('/')[1]))):
        r = results[key]
        print(f'{key:>8s}  ' + '  '.join(f'{r.get(m, {}).get("4", np.nan):.3f} / '
                                         f'{r.get(m, {}).get("8", np.nan):.3f}'
                                         for m in methods))
        for (v, e), count in ahead.items():
            if not baselines or e not in r.get(v, {}) or not all(e in r.get(m, {}) for m in baselines):
                continue   # nothing to be ahead of (e.g. learned_binary alone, to merge later)
            others = [r[m][e] for m in baselines]
            if min(others + [r[v][e]]) < 0.95:
                count[1] += 1
                count[0] += r[v][e] > max(others)
    for (v, e), (won, n) in ahead.items():
        print(f'{e} exposures: {v} ahead of {", ".join(baselines)} in {won} of the {n} splits '
              'where some method is below 95 %')
    if args.png:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
        for ax, e in zip(axes, ('4', '8')):
            for m in methods:
                ax.plot(strengths, [100 * mean[S, m, e] for S in strengths], 'o-', label=m)
            ax.axhline(95, color='gray', lw=0.5, ls='--')
            ax.set_xlabel('cue strength (lightstage synth --strength)')
            ax.set_title(f'{e} exposures, held-out poses, mean of {len(seeds)} splits')
        axes[0].set_ylabel('held-out accuracy (%)')
        axes[0].legend()
        fig.tight_layout()
        fig.savefig(args.png, dpi=100)


if __name__ == '__main__':
    main()
