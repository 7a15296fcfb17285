"""Greedy illumination-pattern search, SNR-optimal and naive baselines, evaluation; the trainer node."""
