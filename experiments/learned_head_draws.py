"""How much of a held-out accuracy is the head's training-noise draw, and do the learned
patterns beat their start once that is averaged out?

Patterns of `learned` and `learned_starts` from a learned_vs_greedy.py JSON; linear SVM heads
(as the learned model's) fit on the training samples rendered with R noise draws (R = 1 for
5 draw seeds, R = 4 stacked for 2); held-out accuracy as `evaluate_learned_heldout` on the
same split.

    PYTHONPATH=src/lightstage_physics:src/mux_classifier:src/mux_trainer \
        .venv/bin/python benchmarks/learned_head_draws.py /work/data/weak0.2 weak0.2_s0.json 0
"""
import json
import sys

import numpy as np
from lightstage_physics.capture_format import load_capture
from mux_classifier.estimator import MuxClassifier
from mux_classifier.learned_model import LearnedModel
from mux_trainer.data import search_data
from mux_trainer.holdout import holdout_split
from mux_trainer.learned import LearnedIlluminationClassifier, evaluate_learned_heldout
from mux_trainer.rendering import add_noise, clean_led_images, image_features, standard_normal

cap, js, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
res = json.load(open(js))['results'][cap]
ms = load_capture(cap, downscale_to=120)
data = search_data(ms, 'sigma3', features='intensity_stats')
tr, te = holdout_split(data, 0.25, seed)
train, test = data.subset(tr), data.subset(te)

def heldout(P, R, draw_seed):
    clean = clean_led_images(train, P)
    rng = np.random.default_rng([draw_seed, 99])
    X = np.vstack([image_features(train, add_noise(train, clean, standard_normal(rng, clean.shape)))
                   for _ in range(R)])
    y = np.tile(train.labels, R)
    clf = MuxClassifier(estimator='linear_svm', hog_config=train.hog_config, features='intensity_stats').fit_features(X, y)
    m = LearnedIlluminationClassifier(n_images=P.shape[1])
    m.patterns_ = P
    m.model_ = LearnedModel(P, np.zeros(X.shape[1]), np.ones(X.shape[1]), [(clf.coef_.T, clf.intercept_)], list(train.class_names))
    return evaluate_learned_heldout(m, test, 4, seed)['accuracy']

for variant in ('learned_starts', 'learned'):
    for k in ('4', '8'):
        P = np.asarray(res[variant][f'patterns_{k}'], np.float32)
        one = [heldout(P, 1, s) for s in range(5)]
        four = [heldout(P, 4, s) for s in range(2)]
        print(f'{cap} seed {seed} {variant} ({res[variant]["chosen_" + k]}) k={k}: R=1 draws '
              + ' '.join(f'{a:.3f}' for a in one) + f' (mean {np.mean(one):.3f}, sd {np.std(one):.3f}); R=4 '
              + ' '.join(f'{a:.3f}' for a in four), flush=True)
