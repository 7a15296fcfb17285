"""How the learned estimator's inner splits rank fixed lights, against the held-out accuracy
the lights give: for one split of a capture, each light's inner score under the two split
classifiers (`CandidateEvaluator(inner_classifier=...)`: 'ridge', the search's fast screen,
the search's fast screen, and 'squared_hinge', the exact linear
SVM, the head's kind), and its held-out accuracy with the model's head fitted on 1 and on 6
noise draws (`head_renders`). docs/research/LEARNED_PATH.md.

The lights, 4 exposures: the light a learned_vs_greedy.py run kept (its JSON), the
raking-sides start (`learned.raking_sides_start` on the paper's stage), and
learned_light_headroom.py's hand-made matrices.

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer \\
        .venv/bin/python benchmarks/learned_light_ranking.py DIR/mix16 --holdout-by instances \\
        --seed 0 --run r5_instances.json
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np
from joblib import Parallel
from lightstage_physics.rig import Rig

from mux_trainer.evaluation import CandidateEvaluator
from mux_trainer.learned import (Descent, Head, LearnedIlluminationClassifier, Starts,
                                 evaluate_learned_heldout, raking_sides_start)
from mux_trainer.search_params import SplitScoring

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from learned_light_headroom import hand_patterns
from learned_vs_greedy import split_capture

SPLIT_CLASSIFIERS = ('ridge', 'squared_hinge')
HEAD_RENDERS = (1, 6)


def lights(run_json: str | None) -> dict:
    out = {}
    if run_json:
        result = next(iter(json.load(open(run_json))['results'].values()))
        out['run_kept'] = np.array(result['learned']['patterns_4'], np.float32)
    out['raking_sides'] = raking_sides_start(Rig.paper_default().site_positions_mm(), 4, 4, None)
    out.update(hand_patterns())
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('capture')
    p.add_argument('--holdout-by', default='poses', choices=('poses', 'instances'))
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--run', help="a learned_vs_greedy.py JSON of this split: its kept 4-exposure light")
    p.add_argument('--n-repeats', type=int, default=400)
    p.add_argument('--n-renders', type=int, default=4)
    p.add_argument('--json', help='write the figures here')
    args = p.parse_args(argv)
    train, test, _ = split_capture(args.capture, args.holdout_by, args.seed)
    print(f'{args.capture}, held out by {args.holdout_by}, split seed {args.seed}: inner score '
          f'({", ".join(SPLIT_CLASSIFIERS)}) and held-out % (head on {" / ".join(map(str, HEAD_RENDERS))} '
          'noise draws), 4 exposures', flush=True)
    out = {}
    for name, P in lights(args.run).items():
        t0 = time.perf_counter()
        row = {}
        for clf in SPLIT_CLASSIFIERS:
            ev = CandidateEvaluator(train, mode='joint', n_repeats=args.n_repeats,
                                    test_fraction=0.25, seed=args.seed, n_jobs=1,
                                    inner_classifier=clf)
            with Parallel(n_jobs=1) as parallel:
                row[clf] = float(ev.score(ev.prepare_column(P[:, :3]), P[:, 3:], parallel).mean())
        for h in HEAD_RENDERS:
            model = LearnedIlluminationClassifier(
                n_images=4, starts=Starts(names=(), patterns={name: P}),
                descent=Descent(fine_tune='none'), head=Head(renders=h),
                scoring=SplitScoring(n_repeats=args.n_repeats), seed=args.seed).fit(train)
            row[f'heldout_{h}'] = evaluate_learned_heldout(model, test, args.n_renders,
                                                           args.seed)['accuracy']
        out[name] = row
        print(f'  {name:18s} inner ' + ' / '.join(f'{100 * row[c]:.1f}' for c in SPLIT_CLASSIFIERS)
              + '   held-out ' + ' / '.join(f'{100 * row[f"heldout_{h}"]:.1f}' for h in HEAD_RENDERS)
              + f'   ({time.perf_counter() - t0:.0f} s)', flush=True)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'args': vars(args), 'lights': out}, f, indent=1)


if __name__ == '__main__':
    main()
