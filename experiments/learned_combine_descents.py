"""One learned fit of several descents, from runs of learned_vs_greedy.py that each ran some
of them (per capture): the union of their candidates, the one the estimator keeps, and its held-out figure.

Every descent draws from a stream of its own and the random start's draws what the stream's first draws were
(`test_each_descent_draws_its_own_stream`), so a run with `--fine-tune random` and one with
`--fine-tune greedy` score exactly what one run of both would. The estimator keeps the best
inner score, the earlier candidate on a tie, in the order: starts, then each descent's
snapshots in `--order`. Candidates the runs share must score the same (checked). The kept
candidate's held-out accuracy is the one of the run that kept it (same patterns, same head).

    .venv/bin/python benchmarks/learned_combine_descents.py r4_poses.json r5_poses.json
"""
from __future__ import annotations

import argparse
import json


def learned_runs(paths) -> dict:
    """{capture: [its result in each JSON]}, for the captures every JSON holds."""
    files = [json.load(open(path))['results'] for path in paths]
    return {capture: [f[capture] for f in files] for capture in files[0]
            if all(capture in f for f in files)}


def combine(runs, k: str, order=('random', 'greedy')):
    scores = {}
    for run in runs:
        for name, value in run['learned'][f'inner_{k}'].items():
            if name in scores and abs(scores[name] - value) > 1e-12:
                raise SystemExit(f'{name} scores {scores[name]} in one run, {value} in another')
            scores[name] = value
    starts = [n for n in scores if '+' not in n]
    snapshots = [n for start in order for n in scores if n.startswith(f'{start}+')]
    best = max(starts + snapshots, key=scores.get)  # max keeps the first of equals
    kept_by = [run for run in runs if run['learned'][f'chosen_{k}'] == best]
    if not kept_by:
        raise SystemExit(f'{best}: no run kept it, so its held-out accuracy was not measured')
    return best, scores[best], kept_by[0]['learned'][k]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('runs', nargs='+', help='JSONs of learned_vs_greedy.py with the same split '
                   '(each capture that all of them hold is combined)')
    p.add_argument('--order', default='random,greedy', help='the descents, in the fit\'s order')
    args = p.parse_args(argv)
    for capture, runs in learned_runs(args.runs).items():
        baseline = next((r['greedy'] for r in runs if 'greedy' in r), {})
        for k in ('4', '8'):
            if not all(f'inner_{k}' in r['learned'] for r in runs):
                continue
            best, inner, accuracy = combine(runs, k, args.order.split(','))
            greedy = f', greedy {100 * baseline[k]:.1f} %' if k in baseline else ''
            print(f'{capture}: {k} exposures: kept {best} (inner {inner:.3f}), held out '
                  f'{100 * accuracy:.1f} %{greedy}')

if __name__ == '__main__':
    main()
