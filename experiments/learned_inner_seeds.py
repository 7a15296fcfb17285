#!/usr/bin/env python3
"""Probe: how much of the inner score of two lights is the draw of the inner splits?

For each split of a capture (held out by poses and by instances, split seeds 0 and 1), the
raking-sides starts of the learned estimator (one per split of the paper stage's low
sites) are scored by its inner splits (exact linear SVM, 400 pose splits, the default
features with the cross-image statistics) under evaluator seeds 0 .. S-1: each seed is
another set of inner splits and another noise draw. Prints the scores and the mean and
standard deviation of the second light's lead. Seed 0 is what a fit with that split seed 0
uses (docs/research/LEARNED_PATH.md: the mix's instances/0 tie).

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer \\
        .venv/bin/python benchmarks/learned_inner_seeds.py DIR/mix16 --seeds 5
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from learned_vs_greedy import split_capture
from lightstage_physics.rig import Rig
from mux_trainer.evaluation import CandidateEvaluator
from mux_trainer.learned import (low_side_splits, raking_name, raking_rng, raking_sides_start,
                                 ratio_offset, stack_features)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('capture')
    p.add_argument('--seeds', type=int, default=5, help='evaluator seeds 0 .. S-1')
    p.add_argument('--exposures', type=int, default=4)
    args = p.parse_args(argv)
    positions = Rig.paper_default().site_positions_mm()
    for holdout in ('poses', 'instances'):
        for split_seed in (0, 1):
            train, _, _ = split_capture(args.capture, holdout, split_seed)
            offset = ratio_offset(train, True)   # the model's features: with the cross-image ones
            lights = {raking_name(split): raking_sides_start(
                          positions, train.n_channels, args.exposures,
                          raking_rng(split_seed, split), split).astype(np.float32)
                      for split in range(len(low_side_splits(positions)))}
            scores = {name: [] for name in lights}
            for seed in range(args.seeds):
                ev = CandidateEvaluator(train, mode='joint', n_repeats=400, seed=seed,
                                        inner_classifier='squared_hinge')
                for name, P in lights.items():
                    X = stack_features(train, ev.images(P), offset)
                    scores[name].append(float(ev.score_features(X).mean()))
            names = list(lights)
            lead = np.subtract(scores[names[1]], scores[names[0]])
            print(f'{holdout}/{split_seed}: ' + '; '.join(
                f'{n} ' + ' '.join(f'{v:.4f}' for v in s) for n, s in scores.items())
                + f'; {names[1]} - {names[0]}: mean {lead.mean():+.4f}, sd {lead.std(ddof=1):.4f}',
                flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
