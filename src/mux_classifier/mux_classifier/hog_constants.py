"""Constants the numpy HOG (`hog`) and the compiled kernel (`hog_kernel`) must share, in a
module of their own: `hog` imports `hog_kernel` only on first use (numba loads slowly), so
neither can hold them for the other."""
from __future__ import annotations

__all__ = ["BLOCK_NORM_EPS"]

BLOCK_NORM_EPS = 1e-5  # skimage's block-normalisation epsilon
