"""Does the learned method keep the candidate light that does best on new samples?

Per family and fold (sample 0, then 1 held out): greedy and SNR-optimal scored on the
held-out samples; the learned method at 4 and 8 exposures, and every candidate light it
scored, each with its own head (`learned.fit_fixed_light_head`, one noise draw of the
held-out samples) beside its inner score, its mean per held-out group of the inner splits,
and two continuous forms of the inner score (`split_scores`: the test samples' mean
squared hinge and mean margin). One JSON line per family; a selection rule is then any
function of the candidates' inner figures, and its held-out accuracy is read off the lines.

    PYTHONPATH=benchmarks:experiments .venv/bin/python experiments/candidate_choice.py SEEDS STRENGTH [CACHE] > OUT
    .venv/bin/python experiments/candidate_choice.py analyse OUT...   # the selection rules
"""
import sys
from types import SimpleNamespace
import json
import numpy as np
import families_benchmark as fb
from lightstage_physics.rig import site_to_led_patterns
from mux_trainer.baselines import SnrOptimalClassifier
from mux_trainer.greedy import GreedyPatternSelector
from mux_trainer.holdout import evaluate_heldout
from mux_trainer.learned import LearnedIlluminationClassifier, Starts, evaluate_learned_heldout
from mux_trainer.learned.head import fit_fixed_light_head, stack_features, ratio_offset
from mux_trainer.search_params import SplitScoring
from mux_trainer.rendering import standardise_columns
def near_then_hinge(c, d):
    """Among the candidates within d of the best inner accuracy, the lowest hinge."""
    top = max(v['inner'] for v in c.values())
    return min((n for n in c if c[n]['inner'] >= top - d), key=lambda n: c[n]['hinge'])


def analyse(paths):
    rows = []
    for f in paths:
        for line in open(f):
            if line[0].isdigit():
                seed, js = line.split(' ', 1); rows.append((int(seed), json.loads(js)))
    print(len(rows), 'families')
    rules = {
      'max_inner': lambda c: max(c, key=lambda n: c[n]['inner']),
      'min_hinge': lambda c: min(c, key=lambda n: c[n]['hinge']),
      'max_margin': lambda c: max(c, key=lambda n: c[n]['margin']),
      'inner_then_hinge': lambda c: max(c, key=lambda n: (c[n]['inner'], -c[n]['hinge'])),
      'near0.01_hinge': lambda c: near_then_hinge(c, 0.01),
      'near0.02_hinge': lambda c: near_then_hinge(c, 0.02),
      'near0.05_hinge': lambda c: near_then_hinge(c, 0.05),
      'oracle': lambda c: max(c, key=lambda n: c[n]['held']),
      'max_min_group': lambda c: max(c, key=lambda n: (min(c[n]['groups']), c[n]['inner'])),
      'mean-std': lambda c: max(c, key=lambda n: np.mean(c[n]['groups']) - np.std(c[n]['groups'])),
      'snr_optimal': lambda c: 'snr_optimal' if 'snr_optimal' in c else max(c, key=lambda n: c[n]['inner']),
      'greedy': lambda c: 'greedy' if 'greedy' in c else max(c, key=lambda n: c[n]['inner']),
      'per_colour': lambda c: 'per_colour' if 'per_colour' in c else max(c, key=lambda n: c[n]['inner']),
      'raking': lambda c: 'raking_sides' if 'raking_sides' in c else max(c, key=lambda n: c[n]['inner']),
    }
    for e, col in (('4', 0), ('8', 1)):
        g = np.array([np.mean([f['greedy'][col] for f in r]) for s, r in rows])
        sn = np.array([np.mean([f['snr'][col] for f in r]) for s, r in rows])
        lh = np.array([np.mean([f['learned'][e]['held'] for f in r]) for s, r in rows])
        lc = np.array([np.mean([f['learned'][e]['cands'][f['learned'][e]['chosen']]['held'] for f in r]) for s, r in rows])
        print(f'e={e}: greedy {100*g.mean():.1f} snr {100*sn.mean():.1f} learned(eval) {100*lh.mean():.1f} learned(cand-head) {100*lc.mean():.1f}')
        for name, rule in rules.items():
            v = np.array([np.mean([f['learned'][e]['cands'][rule(f['learned'][e]['cands'])]['held'] for f in r]) for s, r in rows])
            best = np.maximum(g, sn)
            print(f'   {name:14s} {100*v.mean():5.1f}  -greedy {100*(v-g).mean():+5.1f} -snr {100*(v-sn).mean():+5.1f} behind either {np.mean(v < best - 1e-9):.0%}')


def split_scores(ev, X):
    """The inner splits' accuracies of features X, and two continuous forms of them: the
    test samples' mean squared hinge (one-vs-rest) and mean margin (the true class's score
    less the best other's), from one fit per split."""
    labels = ev.data.labels
    accuracy, hinge, margin = [], [], []
    for t, s in ev.scorer.split_decisions(labels, ev.test_masks, X=standardise_columns(X),
                                          n_classes=ev.n_classes):
        y = -np.ones_like(s)
        y[np.arange(len(t)), labels[t]] = 1
        accuracy.append(np.mean(np.argmax(s, axis=1) == labels[t]))
        hinge.append(float(np.mean(np.sum(np.maximum(0, 1 - y * s) ** 2, axis=1))))
        true = s[np.arange(len(t)), labels[t]]
        other = np.where(y > 0, -np.inf, s).max(axis=1)
        margin.append(float(np.mean(true - other)))
    return np.array(accuracy), float(np.mean(hinge)), float(np.mean(margin))


def measure():
    args = SimpleNamespace(strength=float(sys.argv[2]), samples=4, poses=4, size=60, sample_spread=0.05)
    args.cache = sys.argv[3] if len(sys.argv) > 3 else 'out/families'
    for seed in fb.parse_seeds(sys.argv[1]):
        data = fb.family_data(fb.family_capture(args, seed), 'intensity_stats', 60)
        folds = []
        for f, (train, test) in enumerate(fb.sample_folds(data, (0, 1))):
            tr, te = np.flatnonzero(data.instance != f), np.flatnonzero(data.instance == f)
            sc = SplitScoring(n_repeats=60)
            g = GreedyPatternSelector(mode='per_colour', n_patterns=2, scoring=sc).fit(train)
            s = SnrOptimalClassifier(n_images=2, scoring=sc).fit(train)
            gh = evaluate_heldout(g, test, 4, 0)['accuracy_by_images']; sh = evaluate_heldout(s, test, 4, 0)['accuracy_by_images']
            fold = {'greedy': [gh[1], gh[2]], 'snr': [sh[1], sh[2]], 'learned': {}}
            for e in (4, 8):
                builtin = [n for n in Starts().names if n != 'greedy']
                m = LearnedIlluminationClassifier(n_images=e, starts=Starts(names=tuple(builtin), patterns={'greedy': site_to_led_patterns(g.patterns_[:, :e // 4], train.n_channels)}), scoring=sc).fit(train)
                held = evaluate_learned_heldout(m, test, 4, 0)['accuracy']
                # per candidate: per-group inner accuracies and held-out with its head
                ev = m.evaluator_

                off = ratio_offset(ev.data, m.ratio_stats)
                cands = {}
                for name, P in m.candidates_.items():
                    sa, hinge, margin = split_scores(ev, stack_features(ev.data, ev.images(P), off))
                    groups = ev.split_groups
                    gm = [float(sa[groups == k].mean()) for k in range(groups.max() + 1)]
                    model, scores = fit_fixed_light_head(data, P, tr, te)
                    cands[name] = {'inner': m.candidate_scores_[name], 'groups': gm,
                                   'hinge': hinge, 'margin': margin,
                                   'held': float((scores.argmax(1) == data.labels[te]).mean())}
                fold['learned'][e] = {'held': held, 'chosen': m.chosen_, 'cands': cands}
            folds.append(fold)
        print(seed, json.dumps(folds), flush=True)


if __name__ == '__main__':
    if sys.argv[1] == 'analyse':
        analyse(sys.argv[2:])
    else:
        measure()
