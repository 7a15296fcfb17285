"""The random streams of the learned method (apart from the search's): each start, descent,
inner draw and head draw has a stream of its own, so that no part's draws change another's.
"""
from __future__ import annotations

import zlib

import numpy as np

__all__ = ['LEARNED_STREAM', 'INNER_DRAW_STREAM', 'HEAD_NOISE_STREAM', 'fit_rng', 'inner_seeds',
           'raking_rng', 'descent_rng', 'head_rng']

# seed-sequence tag of every random stream of the learned method
LEARNED_STREAM = 26
INNER_DRAW_STREAM = 7   # the seeds of the inner splits' further draws (`inner_seeds`)
HEAD_NOISE_STREAM = 5   # the head's extra noise draws (`head.head_features`)


def fit_rng(seed: int) -> np.random.Generator:
    """The fit's own stream: the random and per-colour starts' draws, in that order, then
    the random start's descent."""
    return np.random.default_rng([int(seed), LEARNED_STREAM])


def inner_seeds(seed: int, draws: int) -> list[int]:
    """The evaluator seeds of `draws` inner draws: ``seed`` itself (the splits and noise of a
    single draw), then seeds of a stream of their own."""
    more = np.random.SeedSequence([int(seed), LEARNED_STREAM, INNER_DRAW_STREAM]).generate_state(
        max(int(draws) - 1, 0))
    return [int(seed)] + [int(s) for s in more]


def raking_rng(seed: int, split: int) -> np.random.Generator:
    """The stream of the split-th raking start of a fit with `seed` (its later images'
    random halves), one per split so that no start's draws change another's."""
    return np.random.default_rng([int(seed), LEARNED_STREAM, zlib.crc32(b'raking_sides'), 1 + int(split)])


def descent_rng(seed: int, start: str) -> np.random.Generator:
    """The stream of the descent from a start other than the random one (whose descent
    continues `fit_rng`, the stream that drew it)."""
    return np.random.default_rng([int(seed), LEARNED_STREAM, zlib.crc32(str(start).encode())])


def head_rng(seed: int) -> np.random.Generator:
    """The stream of the head's noise draws after the inner splits' one."""
    return np.random.default_rng([int(seed), LEARNED_STREAM, HEAD_NOISE_STREAM])
