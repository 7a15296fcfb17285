"""What light alone can do on a capture: held-out accuracy of a few fixed LED matrices, each
classified as the learned model is (intensity statistics, greedy's linear SVM head), at 4
exposures, on one held-out pose split.

The matrices (rows: site-major LEDs, one column per exposure, levels 0/1):
- per_colour_all: each colour from every site in turn (greedy's per-colour column with all
  sites; the family greedy and SNR-optimal choose within lights one site set per column);
- directional_nir: three images each lit by one low site in every colour, one lit by NIR
  from every site;
- sides_visible_nir: two images lit in every colour from opposite pairs of low sites, one
  by the visible colours from every site, one by NIR from every site;
and the learned model's own light (its defaults without cross-image statistics, 4 exposures) for comparison.
Written by hand after looking at the classes' cues (relief under grazing light, NIR inks);
they show how far the light's family, not the features or the classifier, held greedy back
(docs/research/LEARNED_PATH.md).

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer \\
        .venv/bin/python benchmarks/learned_light_headroom.py /work/data/sweep/weak0.2 [--seed 0]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from lightstage_physics.capture_format import load_capture
from mux_trainer.data import search_data
from mux_trainer.holdout import holdout_split
from mux_trainer.learned import (Descent, LearnedIlluminationClassifier, Starts,
                                 evaluate_learned_heldout)


def hand_patterns(n_sites: int = 8, n_channels: int = 4) -> dict:
    """The fixed (n_sites * n_channels, 4) LED matrices of the module docstring."""
    out = {}
    L = np.zeros((n_channels, n_sites, 4))
    for c in range(n_channels):
        L[c, :, c] = 1
    out['per_colour_all'] = L
    L = np.zeros((n_channels, n_sites, 4))
    for j in range(3):
        L[:, j, j] = 1
    L[3, :, 3] = 1
    out['directional_nir'] = L
    L = np.zeros((n_channels, n_sites, 4))
    L[:, [0, 1], 0] = 1
    L[:, [2, 3], 1] = 1
    L[:3, :, 2] = 1
    L[3, :, 3] = 1
    out['sides_visible_nir'] = L
    return {name: L.transpose(1, 0, 2).reshape(n_sites * n_channels, 4).astype(np.float32)
            for name, L in out.items()}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('capture')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--n-renders', type=int, default=4)
    p.add_argument('--no-learned', action='store_true', help='only the fixed matrices')
    args = p.parse_args(argv)
    data = search_data(load_capture(args.capture, downscale_to=120), 'sigma3',
                       features='intensity_stats')
    tr, te = holdout_split(data, 0.25, args.seed)
    train, test = data.subset(tr), data.subset(te)
    runs = {name: dict(starts=Starts(names=(), patterns={name: P}), descent=Descent(fine_tune='none'))
            for name, P in hand_patterns(data.n_sites, data.n_channels).items()}
    if not args.no_learned:
        runs['learned'] = {}
    print(f'{args.capture}, split seed {args.seed}: held-out accuracy at 4 exposures')
    for name, options in runs.items():
        t0 = time.perf_counter()
        model = LearnedIlluminationClassifier(n_images=4, seed=args.seed, **options).fit(train)
        acc = evaluate_learned_heldout(model, test, args.n_renders, args.seed)['accuracy']
        print(f'  {name:18s} {100 * acc:5.1f} %  (inner splits {100 * model.accuracy_by_images_[4]:.1f} %, '
              f'{time.perf_counter() - t0:.0f} s)', flush=True)


if __name__ == '__main__':
    main()
