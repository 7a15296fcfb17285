"""The starts: candidate lights made without gradient, each scored by the inner splits and
kept as it is where it scores best (docs/LEARNED.md, "Candidate lights and how one is
kept"). All are (sites * channels, k) LED levels, site-major, one image per column.
"""
from __future__ import annotations

import numpy as np
from lightstage_physics.rig import CHANNELS

from ..rendering import SearchData, clean_led_images

__all__ = ['per_colour_start', 'low_side_splits', 'opposite_low_sides', 'raking_name',
           'raking_sides_start', 'random_start']


def per_colour_start(n_sites: int, n_channels: int, k: int, rng) -> np.ndarray:
    """The per-colour start (sites * channels, k), site-major, 0/1: image j lights colour
    j mod 4, at every site for the first four images and at a random half of the sites for
    each later group of four. It keeps the colours apart (a random mixture of colours blurs
    the spectral cue the classes differ by; measured worse in docs/LEARNED.md)."""
    on = np.zeros((n_sites, n_channels, k), np.float32)
    for j in range(k):
        sites = (np.arange(n_sites) if j < n_channels
                 else rng.choice(n_sites, max(1, n_sites // 2), replace=False))
        on[sites, j % n_channels, j] = 1
    return on.reshape(n_sites * n_channels, k)


def low_side_splits(site_positions_mm) -> list[tuple[np.ndarray, np.ndarray]]:
    """The splits of the low sites (elevation at most the median), in azimuth order, into
    two contiguous halves (two groups on two sides of the object), each once, the one whose
    halves' mean horizontal directions are most nearly opposite first (then by that
    measure; ties in azimuth order). Low sites light at a grazing angle, where shallow
    relief casts shading that turns with the light; which axis of the relief shows best
    depends on the object, so each split is a start of its own (`raking_sides_start`)."""
    pos = np.asarray(site_positions_mm, np.float64)
    horizontal = np.hypot(pos[:, 0], pos[:, 1])
    elevation = np.arctan2(pos[:, 2], horizontal)
    low = np.flatnonzero(elevation <= np.median(elevation))
    if low.size < 2:
        low = np.arange(len(pos))
    ring = low[np.argsort(np.arctan2(pos[low, 1], pos[low, 0]))]
    half = ring.size // 2

    def direction(sites):
        v = (pos[sites, :2] / np.maximum(horizontal[sites, None], 1e-9)).mean(axis=0)
        return v / max(np.linalg.norm(v), 1e-9)

    splits, seen = [], set()
    for shift in range(ring.size):
        a, b = np.sort(np.roll(ring, -shift)[:half]), np.sort(np.roll(ring, -shift)[half:])
        key = frozenset((tuple(a), tuple(b)))
        if key not in seen:
            seen.add(key)
            splits.append((a, b))
    # a stable sort: equally opposite splits keep their azimuth order
    return sorted(splits, key=lambda ab: float(direction(ab[0]) @ direction(ab[1])))


def opposite_low_sides(site_positions_mm) -> tuple[np.ndarray, np.ndarray]:
    """The two groups of low sites most nearly opposite (`low_side_splits`' first)."""
    return low_side_splits(site_positions_mm)[0]


def raking_name(split: int) -> str:
    """The start's name for the split-th split of the low sites."""
    return 'raking_sides' if split == 0 else f'raking_sides/{split}'


def raking_sides_start(site_positions_mm, n_channels: int, k: int, rng,
                       split: int = 0) -> np.ndarray:
    """The raking-sides start (sites * channels, k), site-major, 0/1, for k >= 4: every
    colour from one of two groups of low sites on two sides of the object
    (`low_side_splits`, its `split`-th; 0: the most nearly opposite), then from the other
    (relief's shading differs between the two, a flat print's does not), the
    visible colours from every site, NIR from every site (inks that differ in NIR); the
    images after the first four are `per_colour_start`'s (each colour alone). A light a
    person would set up to tell relief and inks apart; measured against the other starts
    in docs/research/LEARNED_PATH.md."""
    if n_channels != len(CHANNELS) or k < 4:
        raise ValueError(f'the raking-sides start needs the {len(CHANNELS)} channels '
                         f'{", ".join(CHANNELS)} and k >= 4; got {n_channels} channels, k {k}')
    positions = np.asarray(site_positions_mm, np.float64)
    n_sites = len(positions)
    splits = low_side_splits(positions)
    if not 0 <= int(split) < len(splits):
        raise ValueError(f'split must be in 0..{len(splits) - 1} (the low sites\' splits), got {split}')
    side_a, side_b = splits[int(split)]
    nir = CHANNELS.index('nir')
    visible = [c for c in range(n_channels) if c != nir]
    on = np.zeros((n_sites, n_channels, 4), np.float32)
    on[side_a, :, 0] = 1
    on[side_b, :, 1] = 1
    on[:, visible, 2] = 1
    on[:, nir, 3] = 1
    first = on.reshape(n_sites * n_channels, 4)
    if k == 4:
        return first
    return np.hstack([first, per_colour_start(n_sites, n_channels, k - 4, rng)])


def random_start(data: SearchData, k: int, rng, headroom: float = 0.5) -> np.ndarray:
    """Levels sigmoid(N(0, 1)) per LED and image: every LED partly on, no two images alike
    (a start whose images are equal would keep them equal: the gradient is symmetric). Each
    image's levels are scaled down where its brightest pixels (the 99.9th percentile over
    the samples) would pass `headroom` of the saturation level: no gradient passes a
    saturated pixel, so a start that saturates the object could not learn."""
    L = data.n_sites * data.n_channels
    P = 1.0 / (1.0 + np.exp(-rng.normal(0.0, 1.0, (L, k))))
    rows = rng.choice(data.n_samples, min(64, data.n_samples), replace=False)
    bright = np.percentile(clean_led_images(data.subset(np.sort(rows)), P), 99.9, axis=(1, 2))
    scale = np.minimum(1.0, headroom * data.max_level / np.maximum(bright, 1e-6))
    return (P * scale).astype(np.float32)

