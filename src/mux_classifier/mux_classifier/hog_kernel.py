"""The compiled HOG kernel behind ``hog.hog_batch`` (numba, one fused pass per image).

For each image: central differences in float32, the magnitude ``sqrt(x*x + y*y)`` in
float32, the orientation bin *without* ``arctan2``, the vote into the cell histogram, then
the block normalisation, before the next image is touched (the image and its histograms
stay in the L1 cache).

Orientation without ``arctan2``: with the gradient folded into the upper half-plane, its
angle is at least the bin edge ``phi`` exactly when ``gy cos(phi) - gx sin(phi) >= 0``, so
the bin is the number of the ``orientations - 1`` interior edges this cross product passes
(unrolled: the edges are a tuple whose length is part of the compiled type). It is
computed in float32; a pixel within a relative 1e-5 of an edge (|cross| below 1e-5 x the
gradient's size, or a gradient within 1e-5 of horizontal) is rare (about 1 pixel in 10^4
on noise) and is binned again exactly as the numpy reference does it, from ``atan2`` in
float64. So every pixel lands in the reference's bin, and the cell histograms, summed in
float64 in the reference's pixel order (the two signed half-planes apart, then added, as
the reference does), are the reference's bit for bit; the block norms are summed in
float64 in a fixed order (the reference's ``einsum`` may sum in another), so the result
agrees with ``hog_batch_numpy`` to a float32 rounding and with skimage as before.

Portable and deterministic: no fastmath, so LLVM neither reorders the float sums nor fuses
multiply-adds; numba compiles for the CPU it runs on (SSE2, AVX2 or AVX-512 alike) and
every one gives the same bits.

Compile cost: the first call in a process that finds no cache compiles the kernel (5-8 s
on the project's 2-core machine lightly loaded, 24 s at load average 6.5; measured by
benchmarks/bench_hog.py); ``cache=True`` keeps the machine code in
``__pycache__`` beside this file, or, where the package folder is read-only for the user,
in numba's per-user cache (``~/.cache/numba`` or ``$NUMBA_CACHE_DIR``), so later processes,
joblib's worker processes included, load it (0.3-1.2 s with numba's import).
scripts/bootstrap.sh compiles it once after installing the package
(``mux_trainer.rendering.compile_kernels``).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .hog_constants import BLOCK_NORM_EPS

_EDGE_TOL = 1e-5     # relative distance to a bin edge below which a pixel is binned exactly
_NORM_CODES = {"L1": 0, "L1-sqrt": 1, "L2": 2, "L2-Hys": 3}
_FINITE_MASK = np.uint32(0x7F800000)  # float32 exponent bits: all set = inf or NaN


@numba.njit(cache=True, nogil=True, inline="always")
def _signed_bin_exact(gx, gy, orientations):
    """The numpy reference's signed bin (0 .. 2 * orientations - 1), from atan2 in float64."""
    if gy == 0:
        return orientations
    s = int(math.atan2(np.float64(gy), np.float64(gx)) * (orientations / math.pi) + orientations)
    if s < 0:
        s = 0
    if s > 2 * orientations - 1:
        s = 2 * orientations - 1
    return s


@numba.njit(cache=True, nogil=True)
def _cell_histograms(img, cell, orientations, edge_cos, edge_sin, hist, wide,
                     gxb, gyb, mag32, mag, sbin):
    """Signed cell histograms (n_cells * n_cells, 2 * orientations) of one image, in float64
    (the reference's signed bins: the lower half-plane's orientations first).

    wide: magnitudes from float64 gradients (the fallback when float32 squares overflow).
    Returns False if a float32 magnitude overflowed (the caller then calls again wide).
    Each row goes through three loops: gradients, then magnitude and bin (branch-free, so
    that LLVM vectorizes them), then the votes (a scatter, scalar).
    """
    H, W = img.shape
    n_cells = H // cell
    span = n_cells * cell
    n_edges = len(edge_cos)
    tol = np.float32(_EDGE_TOL)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    zero_i = np.int32(0)
    minus_one = np.int32(-1)
    n_orient = np.int32(orientations)
    inner = min(span, W - 1)      # columns 1 .. inner-1 have a horizontal gradient
    ok = True
    gxb[0] = zero
    if span == W:
        gxb[W - 1] = zero
    for r in range(span):
        # gradients (skimage: zero on the border rows and columns)
        for c in range(1, inner):
            gxb[c] = img[r, c + 1] - img[r, c - 1]
        if 1 <= r <= H - 2:
            for c in range(span):
                gyb[c] = img[r + 1, c] - img[r - 1, c]
        else:
            for c in range(span):
                gyb[c] = zero
        for c in range(span):
            gx = gxb[c]
            gy = gyb[c]
            if wide:
                mag[c] = math.hypot(np.float64(gx), np.float64(gy))
            else:
                mag32[c] = np.sqrt(gx * gx + gy * gy)
            # fold into the upper half-plane; gy == 0 (any gx) is orientation 0
            lower = gy < zero
            fx = -gx if lower else gx
            fy = -gy if lower else gy
            ax = abs(fx)
            if fy == zero:
                fx = ax
            bound = tol * (ax + fy)
            close = (fy != zero) & (fy <= tol * ax)
            count = zero                       # edges passed, counted in float32 lanes
            for k in range(n_edges):
                d = fy * edge_cos[k] - fx * edge_sin[k]
                count += one if d >= zero else zero
                close = close | (abs(d) <= bound)
            # the reference's signed bin (lower half-plane first); -1: bin it exactly
            sb = np.int32(count) + (zero_i if lower else n_orient)
            sbin[c] = minus_one if close else sb
        base = (r // cell) * n_cells
        for cc in range(n_cells):
            cell_hist = hist[base + cc]
            for c in range(cc * cell, cc * cell + cell):
                s = sbin[c]
                if s < 0:
                    s = _signed_bin_exact(gxb[c], gyb[c], orientations)
                m = mag[c] if wide else np.float64(mag32[c])
                if not math.isfinite(m):
                    ok = False
                cell_hist[s] += m
    return ok


@numba.njit(cache=True, nogil=True)
def _normalize_blocks(cells, block, norm_code, out):
    """Unsigned cell histograms (n_cells, n_cells, o) -> normalised blocks into out (float32),
    in skimage's order (block row, block col, cell row, cell col, bin)."""
    n_cells = cells.shape[0]
    o = cells.shape[2]
    n_blocks = n_cells - block + 1
    size = block * block * o
    buf = np.empty(size)
    k = 0
    eps = BLOCK_NORM_EPS
    for br in range(n_blocks):
        for bc in range(n_blocks):
            j = 0
            for i in range(block):
                for jj in range(block):
                    for b in range(o):
                        buf[j] = cells[br + i, bc + jj, b]
                        j += 1
            if norm_code <= 1:
                total = 0.0
                for j in range(size):
                    total += abs(buf[j])
                scale = total + eps
                for j in range(size):
                    v = buf[j] / scale
                    buf[j] = math.sqrt(v) if norm_code == 1 else v
            else:
                total = 0.0
                for j in range(size):
                    total += buf[j] * buf[j]
                scale = math.sqrt(total + eps * eps)
                for j in range(size):
                    buf[j] = buf[j] / scale
                if norm_code == 3:
                    total = 0.0
                    for j in range(size):
                        v = min(buf[j], 0.2)
                        buf[j] = v
                        total += v * v
                    scale = math.sqrt(total + eps * eps)
                    for j in range(size):
                        buf[j] = buf[j] / scale
            for j in range(size):
                out[k] = np.float32(buf[j])
                k += 1


@numba.njit(cache=True, nogil=True)
def _hog_images(images, cell, block, orientations, norm_code, edge_cos, edge_sin, out, bad):
    """HOG of every image of images (n, H, W) float32 into out (n, n_features) float32;
    bad[i] = True (and out[i] zeros) for an image with a NaN or infinite gray level."""
    n, H, W = images.shape
    n_cells = H // cell
    bits = images.reshape(n * H * W).view(np.uint32)
    hist = np.zeros((n_cells * n_cells, 2 * orientations))
    cells = np.empty((n_cells, n_cells, orientations))
    gxb = np.empty(W, dtype=np.float32)
    gyb = np.empty(W, dtype=np.float32)
    mag32 = np.empty(W, dtype=np.float32)
    mag = np.empty(W)
    sbin = np.empty(W, dtype=np.int32)
    area = float(cell * cell)
    mask = _FINITE_MASK
    exponent_one = np.uint32(0x00800000)
    sign = np.uint32(0x80000000)
    for i in range(n):
        # exponent bits all set (inf, NaN) <=> adding one to the exponent carries into the
        # sign bit: an integer OR over the image, which vectorizes
        nonfinite = np.uint32(0)
        start = i * H * W
        for p in range(start, start + H * W):
            nonfinite |= ((bits[p] & mask) + exponent_one) & sign
        if nonfinite:
            bad[i] = True
            out[i, :] = 0
            continue
        hist[:] = 0.0
        img = images[i]
        if not _cell_histograms(img, cell, orientations, edge_cos, edge_sin, hist, False,
                                gxb, gyb, mag32, mag, sbin):
            hist[:] = 0.0
            _cell_histograms(img, cell, orientations, edge_cos, edge_sin, hist, True,
                             gxb, gyb, mag32, mag, sbin)
        for q in range(n_cells * n_cells):
            for b in range(orientations):
                cells[q // n_cells, q % n_cells, b] = (hist[q, b] + hist[q, orientations + b]) / area
        _normalize_blocks(cells, block, norm_code, out[i])


_EDGES: dict[int, tuple] = {}


def _edges(orientations: int) -> tuple:
    """(cos, sin) tuples of the interior bin edges k * 180 / orientations, k = 1 .. o - 1."""
    edges = _EDGES.get(orientations)
    if edges is None:
        phi = np.arange(1, orientations) * (np.pi / orientations)
        edges = (tuple(np.float32(v) for v in np.cos(phi)),
                 tuple(np.float32(v) for v in np.sin(phi)))
        _EDGES[orientations] = edges
    return edges


def hog_compiled(x: np.ndarray, config) -> tuple[np.ndarray, np.ndarray]:
    """HOG of checked float32 images x (N, H, W) -> (float32 (N, n_features), bool (N,) of
    images holding a NaN or infinite gray level)."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    n = x.shape[0]
    out = np.empty((n, config.n_features), dtype=np.float32)
    bad = np.zeros(n, dtype=np.bool_)
    if n:
        edge_cos, edge_sin = _edges(config.orientations)
        _hog_images(x, config.cell_px, config.block_cells, config.orientations,
                    _NORM_CODES[config.block_norm], edge_cos, edge_sin, out, bad)
    return out, bad
