"""Batched HOG descriptor equal to ``skimage.feature.hog`` for the paper's configuration.

The paper's features are HOG on a 120 x 120 image with 12 x 12-pixel cells, blocks of
10 x 10 cells and 9 unsigned orientation bins, L2-Hys block normalisation: 900 values
per image. ``hog_batch`` computes exactly what

    skimage.feature.hog(img, orientations=9, pixels_per_cell=(12, 12),
                        cells_per_block=(10, 10), block_norm="L2-Hys",
                        feature_vector=True)

computes (to ~1e-6 per value), but for a whole batch of images at once, because the greedy
search extracts HOG from millions of images. ``hog_batch`` runs the compiled kernel of
``hog_kernel`` (numba; one fused pass per image, orientation bins without ``arctan2``;
about 25x skimage, benchmarks/bench_hog.py); ``hog_batch_numpy`` is the pure-numpy
implementation it replaced, kept as the reference it is tested against (same bins and
cell histograms; a value may differ by a float32 rounding of the block norm).

What makes the numpy reference fast (see ``benchmarks/bench_hog.py`` for the figures):

- images are processed in chunks of ``HogConfig.batch_size`` (cache-sized);
- orientations are binned into 18 *signed* 20-degree bins straight from ``arctan2``
  (no floating-point ``% 180``, no ``rad2deg``) and a single ``np.bincount`` over
  (image, cell, signed bin) builds every histogram of the chunk; the two signed halves
  are then folded into the 9 unsigned bins;
- the magnitude is ``sqrt(x*x + y*y)`` in float32, not ``np.hypot`` in float64.

skimage details reproduced on purpose: central differences computed in the input's
float precision (float32 here) with zero gradient on the border rows/columns; a pixel
votes with its full magnitude into the one bin containing its orientation (no
interpolation); each cell histogram is divided by the cell area; blocks are normalised
with ``eps = 1e-5`` (L2-Hys clips at 0.2 and renormalises).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .hog_constants import BLOCK_NORM_EPS

__all__ = ["HogConfig", "hog_batch", "hog_batch_numpy", "hog_reference"]

_BLOCK_NORMS = ("L1", "L1-sqrt", "L2", "L2-Hys")


@dataclass(frozen=True)
class HogConfig:
    """HOG parameters; the defaults are the paper's (900 values per 120 x 120 image)."""

    image_size: int = 120
    cell_px: int = 12
    block_cells: int = 10
    orientations: int = 9
    block_norm: str = "L2-Hys"
    batch_size: int = 8  # images per chunk of hog_batch_numpy (cache-sized); speed only, never values

    def __post_init__(self):
        for name in ("image_size", "cell_px", "block_cells", "orientations", "batch_size"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
                raise ValueError(f"HogConfig.{name} must be a positive integer, got {value!r}")
        if self.block_norm not in _BLOCK_NORMS:
            raise ValueError(
                f"HogConfig.block_norm must be one of {_BLOCK_NORMS}, got {self.block_norm!r}"
            )
        if self.n_cells < self.block_cells:
            raise ValueError(
                f"HogConfig: a {self.image_size} px image has only {self.n_cells} cells of "
                f"{self.cell_px} px per side, fewer than one block of {self.block_cells} cells; "
                "use a larger image_size or smaller cell_px/block_cells"
            )

    @property
    def n_cells(self) -> int:
        """Cells per image side (pixels beyond the last whole cell are ignored, as in skimage)."""
        return self.image_size // self.cell_px

    @property
    def n_blocks(self) -> int:
        """Blocks per image side (blocks overlap with a stride of one cell)."""
        return self.n_cells - self.block_cells + 1

    @property
    def n_features(self) -> int:
        """Length of one image's descriptor (900 for the paper's configuration)."""
        return self.n_blocks ** 2 * self.block_cells ** 2 * self.orientations

    def to_dict(self) -> dict:
        """Plain-JSON form (stored in trained-classifier artifacts)."""
        return {k: (int(v) if isinstance(v, np.integer) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> "HogConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error rather than ignored."""
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"HogConfig: unknown fields {sorted(unknown)}")
        return cls(**data)


def _check_images(images, config: HogConfig) -> np.ndarray:
    arr = np.asarray(images)
    if arr.ndim == 2:
        raise ValueError(
            f"hog_batch expects a batch (N, H, W); got one image of shape {arr.shape}. "
            "Pass images[None] for a single image."
        )
    if arr.ndim != 3:
        raise ValueError(f"hog_batch expects images of shape (N, H, W), got shape {arr.shape}")
    size = config.image_size
    if arr.shape[1:] != (size, size):
        raise ValueError(
            f"hog_batch: images are {arr.shape[1]} x {arr.shape[2]} px but the HOG "
            f"configuration is for {size} x {size}; downscale the images to {size} px "
            "(ModelSet.downscaled) or pass a HogConfig with the matching image_size"
        )
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"hog_batch: images must be numeric, got dtype {arr.dtype}")
    # Gradients are computed in float32, like skimage does for float32 input.
    return np.ascontiguousarray(arr, dtype=np.float32)


def _refuse_non_finite(finite: np.ndarray) -> None:
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise ValueError(
            f"hog_batch: images {bad[:10].tolist()}{' ...' if bad.size > 10 else ''} contain "
            "NaN or infinite gray levels (or values beyond float32 range); replace them "
            "(e.g. np.nan_to_num) before extracting features"
        )


class _Binner:
    """Pre-computed pixel -> (cell, signed bin) index layout for one image size and chunk."""

    def __init__(self, config: HogConfig):
        self.config = config
        n_cells, cell = config.n_cells, config.cell_px
        span = n_cells * cell
        rows = np.arange(span) // cell
        cell_of_pixel = (rows[:, None] * n_cells + rows[None, :]).astype(np.intp)
        self.span = span
        self.n_bins_signed = 2 * config.orientations
        # index of (cell, signed bin 0) for every pixel of the cropped image
        self.cell_base = (cell_of_pixel * self.n_bins_signed).ravel()
        self.per_image = n_cells * n_cells * self.n_bins_signed
        self._offsets_by_n: dict[int, np.ndarray] = {}
        # radians -> bins of 180/orientations degrees. One multiply instead of skimage's
        # rad2deg and comparisons: bins can differ only for angles within ~1e-13 degrees of
        # a bin edge, which float32 gray levels do not produce.
        self.bins_per_radian = config.orientations / np.pi

    def _offsets(self, n: int) -> np.ndarray:
        """Index of (image, cell, signed bin 0) for every pixel of a chunk of n images."""
        offsets = self._offsets_by_n.get(n)
        if offsets is None:
            offsets = self.cell_base[None, :] + (np.arange(n, dtype=np.intp) * self.per_image)[:, None]
            self._offsets_by_n[n] = offsets
        return offsets

    def histograms(self, chunk: np.ndarray) -> np.ndarray:
        """Cell histograms (n, n_cells, n_cells, orientations) in float64, divided by cell area."""
        cfg = self.config
        n = chunk.shape[0]
        span = self.span
        # Central differences in float32 with zero border gradient (skimage), on the full
        # image, then cropped to the whole cells (skimage ignores the remainder).
        g_row = np.zeros(chunk.shape, dtype=np.float32)
        g_col = np.zeros(chunk.shape, dtype=np.float32)
        np.subtract(chunk[:, 2:, :], chunk[:, :-2, :], out=g_row[:, 1:-1, :])
        np.subtract(chunk[:, :, 2:], chunk[:, :, :-2], out=g_col[:, :, 1:-1])
        if span != chunk.shape[1] or span != chunk.shape[2]:
            g_row = np.ascontiguousarray(g_row[:, :span, :span])
            g_col = np.ascontiguousarray(g_col[:, :span, :span])
        g_row = g_row.reshape(n, -1)
        g_col = g_col.reshape(n, -1)
        # Signed bin = floor(angle_deg / width) + orientations, in 0 .. 2*orientations-1;
        # the value is >= 0 (up to rounding, which truncation sends to bin 0), so truncation
        # is floor. The angle is computed in float64 from
        # the float32 gradients, as skimage does.
        angle = np.arctan2(g_row, g_col, dtype=np.float64)
        angle *= self.bins_per_radian
        angle += cfg.orientations
        signed_bin = angle.astype(np.intp)
        # g_row == 0: angle 0 or +-180 deg, all orientation 0 in skimage (180 % 180 == 0)
        np.putmask(signed_bin, g_row == 0, cfg.orientations)
        # (an angle that rounds to +180 with g_row != 0 needs a subnormal g_row; keep it in range)
        np.minimum(signed_bin, self.n_bins_signed - 1, out=signed_bin)
        signed_bin += self._offsets(n)
        # sqrt(x*x + y*y) in float32 (SIMD; 5x faster than float64 or np.hypot here, and
        # within ~1e-7 relative of skimage's float64 hypot); bincount sums in float64.
        with np.errstate(over="ignore"):  # handled below
            magnitude = g_row * g_row
            magnitude += g_col * g_col
        np.sqrt(magnitude, out=magnitude)
        hist = np.bincount(signed_bin.ravel(), weights=magnitude.ravel().astype(np.float64),
                           minlength=n * self.per_image)
        if not np.isfinite(hist).all():
            # |gradient| > ~1.8e19 overflows float32 squares: redo this chunk in float64
            # (float32 underflow of tiny gradients is harmless: eps dominates the norm)
            magnitude = np.hypot(g_row.astype(np.float64), g_col.astype(np.float64))
            hist = np.bincount(signed_bin.ravel(), weights=magnitude.ravel(),
                               minlength=n * self.per_image)
        hist = hist.reshape(n, cfg.n_cells, cfg.n_cells, 2, cfg.orientations)
        # Fold signed bins: angle a and a + 180 are the same unsigned orientation.
        unsigned = hist[:, :, :, 0, :] + hist[:, :, :, 1, :]
        unsigned /= cfg.cell_px * cfg.cell_px
        return unsigned


def _normalize_blocks(hist: np.ndarray, config: HogConfig) -> np.ndarray:
    """(n, nc, nc, o) cell histograms -> (n, n_features) normalised block descriptors."""
    n = hist.shape[0]
    b = config.block_cells
    nb = config.n_blocks
    if nb == 1:
        blocks = hist[:, None, None]  # (n, 1, 1, b, b, o)
    else:
        windows = np.lib.stride_tricks.sliding_window_view(hist, (b, b), axis=(1, 2))
        blocks = np.moveaxis(windows, 3, 5)  # (n, nb, nb, o, b, b) -> (n, nb, nb, b, b, o)
    flat = np.array(blocks.reshape(n, nb * nb, b * b * config.orientations), dtype=np.float64)
    method = config.block_norm
    if method == "L1":
        flat /= np.abs(flat).sum(axis=2, keepdims=True) + BLOCK_NORM_EPS
    elif method == "L1-sqrt":
        flat /= np.abs(flat).sum(axis=2, keepdims=True) + BLOCK_NORM_EPS
        np.sqrt(flat, out=flat)
    else:
        flat /= np.sqrt(np.einsum("nbf,nbf->nb", flat, flat) + BLOCK_NORM_EPS ** 2)[:, :, None]
        if method == "L2-Hys":
            np.minimum(flat, 0.2, out=flat)
            flat /= np.sqrt(np.einsum("nbf,nbf->nb", flat, flat) + BLOCK_NORM_EPS ** 2)[:, :, None]
    return flat.reshape(n, -1).astype(np.float32)


_BINNERS: dict[HogConfig, _Binner] = {}


def hog_batch(images, config: HogConfig = HogConfig()) -> np.ndarray:
    """HOG descriptors of a batch of gray images, by the compiled kernel (``hog_kernel``).

    Parameters and result as :func:`hog_batch_numpy`, the pure-numpy reference it equals
    (the same orientation bins and cell histograms; the block norms' float64 sums may
    differ in their last bits, so a value may differ by a float32 rounding).
    ``config.batch_size`` is the numpy path's; the kernel takes one image at a time.
    """
    x = _check_images(images, config)
    if config.orientations == 1:  # no bin edge to compile a test for
        return hog_batch_numpy(x, config)
    from .hog_kernel import hog_compiled  # numba loads on first use, not on import

    out, bad = hog_compiled(x, config)
    _refuse_non_finite(~bad)
    return out


def hog_batch_numpy(images, config: HogConfig = HogConfig()) -> np.ndarray:
    """HOG descriptors of a batch of gray images, in pure numpy (the reference).

    Parameters
    ----------
    images : array (N, H, W)
        Gray levels (any real dtype; computed in float32 like skimage does for float32
        input). H and W must equal ``config.image_size``.
    config : HogConfig
        HOG parameters; the default is the paper's.

    Returns
    -------
    float32 array (N, config.n_features)
        Row i equals ``skimage.feature.hog(images[i], ..., feature_vector=True)``.
    """
    x = _check_images(images, config)
    _refuse_non_finite(np.isfinite(x).all(axis=(1, 2)))
    key = config
    binner = _BINNERS.get(key)
    if binner is None:
        binner = _BINNERS.setdefault(key, _Binner(config))
    n = x.shape[0]
    out = np.empty((n, config.n_features), dtype=np.float32)
    step = config.batch_size
    for start in range(0, n, step):
        chunk = x[start:start + step]
        out[start:start + step] = _normalize_blocks(binner.histograms(chunk), config)
    return out


def hog_reference(image, config: HogConfig = HogConfig()) -> np.ndarray:
    """The same descriptor computed by ``skimage.feature.hog`` (slow; for tests/benchmarks)."""
    from skimage.feature import hog

    return hog(
        np.asarray(image, dtype=np.float32),
        orientations=config.orientations,
        pixels_per_cell=(config.cell_px, config.cell_px),
        cells_per_block=(config.block_cells, config.block_cells),
        block_norm=config.block_norm,
        feature_vector=True,
    ).astype(np.float32)
