"""Per-image reflectance statistics over the object: what HOG's block normalisation removes.

HOG keeps only the shape of the gradients; how much light an object returns in each band
under each pattern is lost. These features keep it, and ignore where the object lies: per
image, over the object's pixels, the quantiles 10/25/50/75/90 % and the mean of the gray
level, and the mean and quantiles 50/90 % of the gradient magnitude (central differences
in float32, zero on the border rows and columns; relief and texture contrast), in gray
levels: 9 values per image.

The object is each image's own foreground (`object_mask.image_masks`: brighter than the
image's median by a quarter of the way to its 99th percentile; no such pixel: the whole
image), not the stack's: the illumination search adds images to a stack one at a time and
slices the features of the first j images out of a stack's (the prefix layout), so each
image's features must depend on that image alone, never on the other images of its stack.

``intensity_stats_images`` is a compiled kernel (numba, O(pixels) per image, no sort): the
search extracts these features from millions of images. Its quantiles come from histograms
of ``N_BINS`` bins, over the image's [min, max] for the gray levels (the mask's median and
99th percentile too) and over [0, the object's largest gradient] for the gradients: an
order statistic is placed inside its bin by its rank among the bin's pixels, and
np.percentile's linear interpolation between the two order statistics around a quantile is
then done on these. So every quantile is within one bin (range / N_BINS) of the exact one
(plus a float32 rounding of the bin index); the mask's threshold is too, so pixels within a
bin of it may fall on the other side than in the exact mask (and an image whose 99th
percentile lies within a bin of its median, e.g. more than half of it at its top level, may
get a partial mask where the exact rule takes the whole image). Integer images (an integer
dtype) spanning fewer than N_BINS levels, such as 10-bit camera frames, get one bin per
level: their level quantiles and mask are exact. Means are float64 sums over the same
pixels, so they equal the reference's wherever the masks agree. Gradients are the
reference's bit for bit. ``intensity_stats_images_numpy`` is the exact reference
(np.percentile), kept to test the kernel against.

Speed (benchmarks/bench_intensity_stats.py): about half the HOG grid's time per 120 x 120
image for small objects, three quarters for objects covering 40 % of it. Portable and
deterministic as hog_kernel (no fastmath: the same bits on every CPU). The first call in a
process without numba's cache compiles the kernel (seconds); ``cache=True`` keeps it.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .object_mask import MASK_FRACTION, image_masks

__all__ = ["intensity_stats", "intensity_stats_images", "intensity_stats_images_numpy",
           "N_STATS", "N_BINS"]

LEVEL_QUANTILES = (10, 25, 50, 75, 90)
GRADIENT_QUANTILES = (50, 90)
N_STATS = len(LEVEL_QUANTILES) + 1 + 1 + len(GRADIENT_QUANTILES)
N_BINS = 2048  # histogram bins of the kernel's quantiles (8 KiB of counts: stays in L1)
_GROUP = 32  # bins summed into one step of the quantile walk (N_BINS is a multiple)

_MASK_QUANTILES = np.array([0.50, 0.99])  # the floor level and the bright end
_LEVEL_FRACTIONS = np.array(LEVEL_QUANTILES) / 100.0
_GRADIENT_FRACTIONS = np.array(GRADIENT_QUANTILES) / 100.0


def intensity_stats(stacks: np.ndarray) -> np.ndarray:
    """(n, k, H, W) -> float32 (n, k * 9) object statistics, concatenated in image order;
    each image's 9 depend on that image alone (`intensity_stats_images`)."""
    arr = np.asarray(stacks)
    if arr.ndim != 4:
        raise ValueError("intensity_stats expects stacks of shape (n, k, H, W), "
                         f"got shape {arr.shape}")
    n, k, H, W = arr.shape
    return intensity_stats_images(arr.reshape(n * k, H, W)).reshape(n, k * N_STATS)


def intensity_stats_images(images: np.ndarray) -> np.ndarray:
    """Gray images (N, H, W), any integer or float dtype -> float32 (N, 9): per image, over
    its own object's pixels, the gray-level quantiles 10/25/50/75/90 %, the mean gray level,
    the mean gradient magnitude and its quantiles 50/90 % (compiled; quantiles within one
    histogram bin of the exact ones, see the module docstring)."""
    arr = np.asarray(images)
    x = _check_images(arr, "intensity_stats_images")
    out = np.empty((len(x), N_STATS), np.float32)
    bad = np.zeros(len(x), np.bool_)
    if len(x):
        _stats_images(x, np.issubdtype(arr.dtype, np.integer), MASK_FRACTION, _MASK_QUANTILES,
                      _LEVEL_FRACTIONS, _GRADIENT_FRACTIONS, N_BINS, out, bad)
    _refuse_bad(bad, "intensity_stats_images")
    return out


def intensity_stats_images_numpy(images: np.ndarray) -> np.ndarray:
    """`intensity_stats_images` computed exactly in numpy (np.percentile; the reference)."""
    arr = _check_images(images, "intensity_stats_images_numpy")
    masks = image_masks(arr)
    grad = _gradient_magnitude(arr)
    out = np.zeros((len(arr), N_STATS), np.float32)
    for i in range(len(arr)):
        mask = masks[i] if masks[i].any() else np.ones_like(masks[i])  # no object: whole image
        levels, grads = arr[i][mask], grad[i][mask]
        out[i, :5] = np.percentile(levels, LEVEL_QUANTILES)
        out[i, 5] = levels.mean(dtype=np.float64)
        out[i, 6] = grads.mean(dtype=np.float64)
        out[i, 7:] = np.percentile(grads, GRADIENT_QUANTILES)
    _refuse_bad(~np.isfinite(out).all(axis=1), "intensity_stats_images_numpy")
    return out


def _gradient_magnitude(arr: np.ndarray) -> np.ndarray:
    """Central-difference gradient magnitude of float32 images (N, H, W), zero on the border
    rows (row gradient) and columns (column gradient), in float32."""
    gr = np.zeros_like(arr)
    gc = np.zeros_like(arr)
    gr[:, 1:-1, :] = arr[:, 2:, :] - arr[:, :-2, :]
    gc[:, :, 1:-1] = arr[:, :, 2:] - arr[:, :, :-2]
    return np.sqrt(gr * gr + gc * gc)


def _check_images(images, who: str) -> np.ndarray:
    arr = np.asarray(images)
    if arr.ndim != 3:
        raise ValueError(f"{who} expects gray images of shape (N, H, W), got shape {arr.shape}"
                         + (" (pass images[None] for a single image)" if arr.ndim == 2 else ""))
    if arr.shape[1] * arr.shape[2] == 0:
        raise ValueError(f"{who}: images of {arr.shape[1]} x {arr.shape[2]} px have no pixel")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"{who}: images must hold integer or float gray levels, "
                         f"got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def _refuse_bad(bad: np.ndarray, who: str) -> None:
    if bad.any():
        idx = np.flatnonzero(bad)
        raise ValueError(
            f"{who}: images {idx[:10].tolist()}{' ...' if idx.size > 10 else ''} contain NaN or "
            "infinite gray levels, or levels so large (beyond ~1e19) that their float32 "
            "gradients overflow; replace them (e.g. np.nan_to_num) before extracting features")


# --- the compiled kernel -------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def _order_stats(hist, groups, first, first_count, first_edge, lo, width, exact, ranks, values):
    """Estimated order statistics (0-based ranks, ascending) of the pixels counted in hist
    from bin `first` on, whose count and lower edge are first_count and first_edge (a bin
    cut by the object's threshold); bin b spans [lo + b width, lo + (b + 1) width). The
    r-th of a bin's c pixels is put at (r + 1/2) / c of the bin: within one bin width;
    exact: every bin holds one level, its lower edge. groups: hist's sums over _GROUP bins,
    to step over whole groups (the walk is then ~n_bins / _GROUP steps, not n_bins)."""
    last = len(hist) - 1
    b = first
    count = first_count
    below = 0  # pixels in the bins before b
    for j in range(len(ranks)):
        r = ranks[j]
        while below + count <= r and b < last:
            below += count
            b += 1
            while b % _GROUP == 0 and b + _GROUP <= last and below + groups[b // _GROUP] <= r:
                below += groups[b // _GROUP]
                b += _GROUP
            count = hist[b]
        edge = first_edge if b == first else lo + b * width
        if exact:
            values[j] = edge
        else:
            top = lo + (b + 1) * width
            values[j] = edge + (r - below + 0.5) / max(count, 1) * (top - edge)


@numba.njit(cache=True, nogil=True)
def _group_sums(hist, groups):
    """groups[g] = the count of hist's bins g * _GROUP .. (g + 1) * _GROUP - 1."""
    for g in range(len(groups)):
        total = 0
        for b in range(g * _GROUP, (g + 1) * _GROUP):
            total += hist[b]
        groups[g] = total


@numba.njit(cache=True, nogil=True)
def _quantiles(hist, groups, first, first_count, first_edge, lo, width, exact, n, fractions,
               ranks, values, out):
    """np.percentile's linear quantiles (fractions, ascending) of n pixels counted in hist,
    interpolated between the estimated order statistics around each one, into out."""
    m = len(fractions)
    for j in range(m):
        k = int(math.floor(fractions[j] * (n - 1)))
        ranks[2 * j] = k
        ranks[2 * j + 1] = min(k + 1, n - 1)
    _order_stats(hist, groups, first, first_count, first_edge, lo, width, exact, ranks[:2 * m],
                 values)
    for j in range(m):
        pos = fractions[j] * (n - 1)
        a = values[2 * j]
        out[j] = a + (values[2 * j + 1] - a) * (pos - math.floor(pos))


@numba.njit(cache=True, nogil=True)
def _histogram(values, n, lo, scale, hist, bins):
    """Count values[:n] (float32) into hist, bin b = int((v - lo) * scale) in float32 (the
    last bin also takes the top), and keep each value's bin in bins. The float32 steps are
    monotonic in v, so a threshold's bin splits the values: the ones above it lie in that
    bin or later. The bins are computed first, in a loop LLVM vectorizes, then counted."""
    lo32 = np.float32(lo)
    scale32 = np.float32(scale)
    last = np.float32(len(hist) - 1)
    for p in range(n):
        bins[p] = np.int32(min((values[p] - lo32) * scale32, last))
    hist[:] = 0
    for p in range(n):
        hist[bins[p]] += 1


@numba.njit(cache=True, nogil=True)
def _bin(v, lo, scale, n_bins):
    """The bin `_histogram` gives a float32 value v."""
    return np.int32(min((np.float32(v) - np.float32(lo)) * np.float32(scale),
                        np.float32(n_bins - 1)))


@numba.njit(cache=True, nogil=True)
def _range_if_finite(keys):
    """(smallest, largest) order key of a float32 image's bits viewed as int32 (signed int
    order of `key = bits ^ ((bits >> 31) & 0x7FFFFFFF)` is the float order), and whether
    every level is finite: integer min, max and OR, which LLVM vectorizes."""
    mantissa = np.int32(0x7FFFFFFF)
    exponent = np.int32(0x7F800000)
    lo = mantissa
    hi = -mantissa - 1
    nonfinite = np.int32(0)
    for p in range(len(keys)):
        b = keys[p]
        nonfinite |= np.int32((b & exponent) == exponent)
        k = b ^ ((b >> 31) & mantissa)
        lo = min(lo, k)
        hi = max(hi, k)
    return lo, hi, nonfinite == 0


@numba.njit(cache=True, nogil=True)
def _object_pass(img, threshold, bins, cut_bin, object_levels, object_grads, gr_row, gc_row):
    """The object's pixels of img (H, W): gray level above threshold. Their levels go to
    object_levels[:count] and their gradient magnitudes to object_grads[:count] (float32,
    bit for bit the numpy reference's). Returns count, the largest gradient and how many
    of them lie in the level bin cut_bin (bins: each pixel's level bin).

    The squared gradients are computed for every pixel in branch-free loops (vectorized),
    the square roots (the costly part) only for the object's pixels, after compaction."""
    H, W = img.shape
    zero = np.float32(0.0)
    count = 0
    in_cut = 0
    square_max = zero
    gc_row[0] = zero
    gc_row[W - 1] = zero
    for r in range(H):
        hit = False  # any object pixel in this row (a vectorized OR); else skip the row
        for c in range(W):
            hit |= img[r, c] > threshold
        if not hit:
            continue
        if 0 < r < H - 1:
            for c in range(W):
                gr_row[c] = img[r + 1, c] - img[r - 1, c]
        else:
            gr_row[:] = zero
        for c in range(1, W - 1):
            gc_row[c] = img[r, c + 1] - img[r, c - 1]
        for c in range(W):
            gr_row[c] = gr_row[c] * gr_row[c] + gc_row[c] * gc_row[c]
        for c in range(W):
            v = img[r, c]
            if v > threshold:
                square = gr_row[c]
                object_levels[count] = v
                object_grads[count] = square
                square_max = max(square_max, square)
                in_cut += bins[r * W + c] == cut_bin
                count += 1
    for p in range(count):
        object_grads[p] = np.sqrt(object_grads[p])
    return count, np.sqrt(square_max), in_cut  # sqrt is monotonic and correctly rounded


@numba.njit(cache=True, nogil=True)
def _sum(values, n):
    """Sum of values[:n] in float64, in four interleaved partial sums (independent chains
    of additions run in parallel; a fixed order, so the same bits on every CPU)."""
    s0 = s1 = s2 = s3 = 0.0
    m = n - n % 4
    for p in range(0, m, 4):
        s0 += values[p]
        s1 += values[p + 1]
        s2 += values[p + 2]
        s3 += values[p + 3]
    for p in range(m, n):
        s0 += values[p]
    return (s0 + s1) + (s2 + s3)


@numba.njit(cache=True, nogil=True)
def _stats_images(images, integer_levels, fraction, mask_fractions, level_fractions,
                  grad_fractions, n_bins, out, bad):
    """The 9 statistics of every image of images (N, H, W) float32 into out (N, 9); bad[i]
    (and out[i] zeros) for an image with a non-finite level or gradient. integer_levels:
    the levels are whole numbers (an integer dtype), so an image spanning fewer than n_bins
    levels gets one bin per level, and exact level quantiles and mask."""
    n, H, W = images.shape
    P = H * W
    level_hist = np.zeros(n_bins, np.int32)
    grad_hist = np.zeros(n_bins, np.int32)
    level_groups = np.empty(n_bins // _GROUP, np.int64)
    grad_groups = np.empty(n_bins // _GROUP, np.int64)
    bins = np.empty(P, np.int32)
    object_levels = np.empty(P, np.float32)
    object_grads = np.empty(P, np.float32)
    gr_row = np.empty(W, np.float32)
    gc_row = np.empty(W, np.float32)
    ranks = np.empty(2 * max(len(mask_fractions), len(level_fractions), len(grad_fractions)),
                     np.int64)
    values = np.empty(len(ranks))
    mask_levels = np.empty(len(mask_fractions))
    keys = images.reshape(n * P).view(np.int32)
    key = np.empty(2, np.int32)
    key_levels = key.view(np.float32)
    mantissa = np.int32(0x7FFFFFFF)
    for i in range(n):
        img = images[i]
        pix = img.reshape(P)
        key[0], key[1], finite = _range_if_finite(keys[i * P:(i + 1) * P])
        if not finite:
            bad[i] = True
            out[i, :] = 0
            continue
        for j in range(2):  # order keys back to float32 bits
            key[j] ^= (key[j] >> 31) & mantissa
        lo = np.float64(key_levels[0])
        exact = integer_levels and np.float64(key_levels[1]) - lo < n_bins
        width = 1.0 if exact else (np.float64(key_levels[1]) - lo) / n_bins
        scale = 1.0 / width if width > 0 else 0.0
        _histogram(pix, P, lo, scale, level_hist, bins)
        # the object: brighter than the floor (median) by `fraction` of the way to the top
        _group_sums(level_hist, level_groups)
        _quantiles(level_hist, level_groups, 0, level_hist[0], lo, lo, width, exact, P,
                   mask_fractions, ranks, values, mask_levels)
        floor, top = mask_levels[0], mask_levels[1]
        threshold = floor + fraction * max(top - floor, 1e-6)
        cut_bin = _bin(threshold, lo, scale, n_bins)
        first_edge = lo + cut_bin if exact else threshold  # a bin's pixels above it
        count, grad_max, in_cut = _object_pass(img, threshold, bins, cut_bin, object_levels,
                                               object_grads, gr_row, gc_row)
        if count == 0:  # no pixel stands out: the whole image stands in for the object
            cut_bin = 0
            first_edge = lo
            count, grad_max, in_cut = _object_pass(img, -np.inf, bins, cut_bin, object_levels,
                                                   object_grads, gr_row, gc_row)
        if not math.isfinite(grad_max):  # float32 gradients overflowed
            bad[i] = True
            out[i, :] = 0
            continue
        o = out[i]
        _quantiles(level_hist, level_groups, cut_bin, in_cut, first_edge, lo, width, exact, count,
                   level_fractions, ranks, values, o[:5])
        o[5] = _sum(object_levels, count) / count
        o[6] = _sum(object_grads, count) / count
        g_width = np.float64(grad_max) / n_bins
        g_scale = 1.0 / g_width if g_width > 0 else 0.0
        _histogram(object_grads, count, 0.0, g_scale, grad_hist, bins)
        _group_sums(grad_hist, grad_groups)
        _quantiles(grad_hist, grad_groups, 0, grad_hist[0], 0.0, 0.0, g_width, False, count,
                   grad_fractions, ranks, values, o[7:])
