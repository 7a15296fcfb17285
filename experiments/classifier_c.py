"""Does another regularisation of the classifiers help on new physical samples, fixed or
chosen by the grouped inner splits?

Per family and fold (sample 0, then 1 held out): greedy's 2 columns and SNR-optimal's first
2, each refitted as a fixed matrix with the split scorer's and the kept classifier's C in
0.01, 0.1, 1, 10; the inner figure and the held-out accuracy at 1 and 2 columns. One JSON
line per family.

    PYTHONPATH=benchmarks:experiments .venv/bin/python experiments/classifier_c.py SEEDS STRENGTH
"""
import json
import sys
from types import SimpleNamespace

import families_benchmark as fb
from mux_trainer.baselines import FixedPatternClassifier, SnrOptimalClassifier
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.holdout import evaluate_heldout
from mux_trainer.search_params import FinalClassifier, SplitScoring
CS = (0.01, 0.1, 1.0, 10.0)
args = SimpleNamespace(strength=float(sys.argv[2]), samples=4, poses=4, size=60, sample_spread=0.05, cache='out/families')
for seed in fb.parse_seeds(sys.argv[1]):
    data = fb.family_data(fb.family_capture(args, seed), 'intensity_stats', 60)
    folds = []
    for f, (train, test) in enumerate(fb.sample_folds(data, (0, 1))):
        g = GreedyPatternSelector(mode='per_colour', n_patterns=2, scoring=SplitScoring(n_repeats=60)).fit(train)
        snr = SnrOptimalClassifier(n_images=2, scoring=SplitScoring(n_repeats=60)).fit(train)
        fold = {}
        for name, P in (('greedy', g.patterns_), ('snr', snr.patterns_)):
            for C in CS:
                m = FixedPatternClassifier(patterns=P, scoring=SplitScoring(n_repeats=60, C=C), final_classifier=FinalClassifier(C=C)).fit(train)
                h = evaluate_heldout(m, test, 4, 0)['accuracy_by_images']
                fold[f'{name}_{C}'] = {'held': [h[1], h[2]], 'inner': [m.accuracy_by_images_[1], m.accuracy_by_images_[2]]}
        folds.append(fold)
    print(seed, json.dumps(folds), flush=True)
