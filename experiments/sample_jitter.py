"""Do training renders with per-sample gain jitter help on new physical samples?

Each training fold's physical samples get `copies` jittered copies: every (sample, colour
channel) its own gain exp(sigma * N(0, 1)), the same over the sample's poses, sigma the
measured spread of the log brightness between samples of a class (times `scale`); the
copies keep their sample's number, so the inner splits hold them out with it. Every method
of `families_benchmark.run_fold` is trained on the jittered fold and scored on the held-out
samples (untouched), 2 folds per family. One JSON line per family.

    PYTHONPATH=benchmarks:experiments .venv/bin/python experiments/sample_jitter.py \
        SEEDS STRENGTH COPIES SCALE METHODS     # e.g. 0-3 0.5 2 1 naive,snr_optimal,greedy,learned
"""
import sys
from types import SimpleNamespace
import json
import numpy as np
from dataclasses import replace
import families_benchmark as fb

def between_sample_spread(data):
    b = data.basis.sum(axis=(0, 3)).astype(np.float64)   # (channels, n)
    out = []
    for c in np.unique(data.labels):
        for ch in range(b.shape[0]):
            per = [np.log(b[ch, (data.labels == c) & (data.instance == s)].mean()) for s in np.unique(data.instance[data.labels == c])]
            if len(per) > 1:
                out.append(np.std(per, ddof=1))
    return float(np.mean(out))

def jittered(data, copies, sigma, seed=0):
    rng = np.random.default_rng(seed)
    parts = [data.basis]
    for _ in range(copies):
        # one factor per (physical sample, channel), the same over its poses
        keys = data.labels * 1000 + data.instance
        uniq, inv = np.unique(keys, return_inverse=True)
        f = np.exp(sigma * rng.standard_normal((len(uniq), data.n_channels))).astype(np.float32)[inv]  # (n, ch)
        parts.append(data.basis * f.T[None, :, :, None])
    return replace(data, basis=np.concatenate(parts, axis=2), labels=np.tile(data.labels, copies + 1),
                   pose_index=np.tile(data.pose_index, copies + 1), instance=np.tile(data.instance, copies + 1))

if __name__ == '__main__':
    copies = int(sys.argv[3]); scale = float(sys.argv[4])
    args = SimpleNamespace(strength=float(sys.argv[2]), samples=4, poses=4, size=60, sample_spread=0.05)
    args.cache='out/families'; args.n_repeats=60; args.inner_groups='auto'; args.seed=0; args.n_renders=4
    args.methods = sys.argv[5].split(',')
    for seed in fb.parse_seeds(sys.argv[1]):
        data = fb.family_data(fb.family_capture(args, seed), 'intensity_stats', 60)
        folds = []
        for f, (train, test) in enumerate(fb.sample_folds(data, (0, 1))):
            sig = between_sample_spread(train) * scale
            if copies:
                train = jittered(train, copies, sig, seed=f)
            folds.append(fb.run_fold(train, test, args))
            folds[-1]['sigma'] = sig
        out = {m: {k: float(np.mean([fo[m][k] for fo in folds])) for k in ('4', '8', 'inner4', 'inner8')} for m in folds[0] if m != 'sigma'}
        out['sigma'] = float(np.mean([fo['sigma'] for fo in folds]))
        print(seed, json.dumps(out), flush=True)
