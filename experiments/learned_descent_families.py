"""Does a descent on the LED levels beat the best start on new physical samples?

Per family and fold (sample 0, then 1 held out): the learned method at 4 and 8 exposures
with its starts alone and with `Descent(max_steps=STEPS)` from its default starts (the
random one, greedy's columns and the best raking split; the loss's folds hold out whole
training samples, `inner_groups` auto), snapshots every STEPS / 4 steps scored by the inner
splits beside the starts; the held-out accuracy, the candidate kept, its step, the fit's
seconds and the inner estimate. One JSON line per family.

    PYTHONPATH=benchmarks:experiments .venv/bin/python experiments/learned_descent_families.py SEEDS STRENGTH STEPS
"""
import json
import sys
import time
from types import SimpleNamespace

import families_benchmark as fb
from lightstage_physics.rig import site_to_led_patterns
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.learned import Descent, LearnedIlluminationClassifier, Starts, evaluate_learned_heldout
from mux_trainer.search_params import SplitScoring

steps = int(sys.argv[3])
args = SimpleNamespace(strength=float(sys.argv[2]), samples=4, poses=4, size=60, sample_spread=0.05, cache='out/families')
for seed in fb.parse_seeds(sys.argv[1]):
    data = fb.family_data(fb.family_capture(args, seed), 'intensity_stats', 60)
    out = {}
    for f, (train, test) in enumerate(fb.sample_folds(data, (0, 1))):
        sc = SplitScoring(n_repeats=60)
        g = GreedyPatternSelector(mode='per_colour', n_patterns=2, scoring=sc).fit(train)
        for e in (4, 8):
            builtin = tuple(n for n in Starts().names if n != 'greedy')
            starts = Starts(names=builtin, patterns={'greedy': site_to_led_patterns(g.patterns_[:, :e // 4], train.n_channels)})
            for s in (0, steps):
                t0 = time.perf_counter()
                m = LearnedIlluminationClassifier(n_images=e, starts=starts, scoring=sc,
                                                  descent=Descent(max_steps=s, eval_every=max(1, steps // 4))).fit(train)
                held = evaluate_learned_heldout(m, test, 4, 0)['accuracy']
                r = out.setdefault(f'{e}_{s}', {'held': [], 'chosen': [], 'step': [], 'seconds': [], 'inner': []})
                r['held'].append(held); r['chosen'].append(m.chosen_); r['step'].append(m.best_step_)
                r['seconds'].append(time.perf_counter() - t0); r['inner'].append(m.inner_estimate_['accuracy'])
    print(seed, json.dumps(out), flush=True)
