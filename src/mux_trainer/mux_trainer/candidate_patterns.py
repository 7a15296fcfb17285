"""Candidate illumination patterns: the paper's site patterns and the joint LED patterns.

A site pattern is a length-8 binary vector (one entry per illumination site); in the paper's
per-colour mode it is applied to each colour separately and yields 4 images (R, G, B, NIR).
An LED pattern is a length-32 vector in site-major order (`led = site * 4 + channel`) and
yields one image. Matrices of k patterns are `(8, k)` and `(32, k)` (docs/ARCHITECTURE.md).
"""
from __future__ import annotations

import numpy as np
from lightstage_physics.rig import N_LEDS, N_SITES

__all__ = ['all_leds_on', 'bits_of', 'gray_code', 'pattern_code', 'site_pattern_candidates']


def gray_code(n_bits: int) -> np.ndarray:
    """The reflected binary Gray code: 2**n_bits integers, consecutive ones differ by one bit."""
    codes = np.arange(2 ** n_bits, dtype=np.int64)
    return codes ^ (codes >> 1)


def bits_of(codes: np.ndarray, n_bits: int) -> np.ndarray:
    """Integers -> (n_bits, len(codes)) binary float32 matrix; bit i of a code is row i."""
    codes = np.asarray(codes, dtype=np.int64)
    return ((codes[None, :] >> np.arange(n_bits)[:, None]) & 1).astype(np.float32)


def site_pattern_candidates(n_sites: int = N_SITES, min_lit: int = 1,
                            max_lit: int | None = None) -> np.ndarray:
    """The paper's candidate site patterns, in Gray-code order, as an `(n_sites, n)` matrix.

    The released code enumerates the patterns with 1..7 of the 8 sites lit (254; all-off
    and all-on excluded). Gray-code order lets a renderer visit them with one added or
    removed site image per step (most consecutive candidates differ by exactly one site).
    """
    max_lit = n_sites - 1 if max_lit is None else max_lit
    if not 0 <= min_lit <= max_lit <= n_sites:
        raise ValueError(f'need 0 <= min_lit <= max_lit <= {n_sites}, got {min_lit}, {max_lit}')
    codes = gray_code(n_sites)
    lit = bits_of(codes, n_sites).sum(axis=0)
    keep = (lit >= min_lit) & (lit <= max_lit)
    return bits_of(codes[keep], n_sites)


def pattern_code(pattern: np.ndarray) -> int:
    """A binary pattern -> its integer code (bit i = entry i); used as a stable key."""
    bits = np.asarray(pattern).ravel() > 0.5
    return int(np.sum(bits.astype(np.int64) << np.arange(bits.size, dtype=np.int64)))


def all_leds_on(n_leds: int = N_LEDS) -> np.ndarray:
    """The naive baseline's single LED pattern: every LED on, `(n_leds, 1)`."""
    return np.ones((n_leds, 1), dtype=np.float32)
