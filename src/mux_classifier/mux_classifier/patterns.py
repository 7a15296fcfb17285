"""Site patterns -> LED patterns (site-major LED order, ``led = site * 4 + channel``).

In the paper's per-colour mode a site pattern (length 8) is applied to each colour in
turn, so site-pattern column j gives 4 images, in the order red, green, blue, NIR:
image ``4*j + c`` lights LED ``site*4 + c`` for every site lit in column j.
"""
from __future__ import annotations

import numpy as np

N_SITES = 8
N_CHANNELS = 4
N_LEDS = N_SITES * N_CHANNELS

__all__ = ["N_SITES", "N_CHANNELS", "N_LEDS", "site_to_led_patterns"]


def site_to_led_patterns(site_patterns, n_channels: int = N_CHANNELS) -> np.ndarray:
    """(n_sites, m) site matrix -> (n_sites * n_channels, n_channels * m) LED matrix (float32)."""
    W = np.asarray(site_patterns, dtype=np.float32)
    if W.ndim != 2:
        raise ValueError(f"site patterns must be a matrix (n_sites, m), got shape {W.shape}")
    n_sites, m = W.shape
    P = np.zeros((n_sites, n_channels, m, n_channels), dtype=np.float32)
    for c in range(n_channels):
        P[:, c, :, c] = W
    return P.reshape(n_sites * n_channels, m * n_channels)
