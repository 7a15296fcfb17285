"""Flat and low-relief objects for the synthetic stage: coins and banknote-like prints.

Their classes differ only under particular light, not in outline:

- ``coin``: a brass token with a motif embossed 0.15 mm deep (real) against a flat printed
  copy of the same token (fake). With every LED on the two look alike; a grazing site casts
  shading, shadows and glints that turn with the light on the embossed one and stay put on
  the print.
- ``note``: a paper note printed with a design; the real note's inks are transparent in
  NIR (the NIR image shows plain paper, brighter), the copy's inks absorb NIR too. Visible
  images look alike.
- ``seal``: a certificate's embossed seal on matte paper: the real seal's design is pressed
  0.2 mm into relief (and inked), the copy is a flat print of the same design in the same
  inks, reproducing the relief's shading under diffuse light. Shallow relief on matte
  paper: a faint cue that only light from one side brings out of the noise (the raking
  light a clerk tilts a document under).

The printed copies (``coin``, ``seal``) are printed from a photograph of the original
under every LED at once (`PRINTED_RELIEF_MM`): with every LED on they return what the
original returns, pixel for pixel.

Each real sample has its own motif/design (a smoothed random field on the object's own
grid), and each fake is a copy of the real sample with the same number (a forger copies a
specimen: the same design, size and tint; `synth._instance_seed`). So the two classes hold
the same designs and a classifier must learn relief vs print or NIR ink, not which designs
it saw. Geometry follows the pose (centre, in-plane rotation, scale), drawn apart for the
copy and its original; materials are in `materials.MATERIALS`.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

FLAT_TYPES = ("coin", "note", "seal")
COIN_RADIUS_MM = 26.0
COIN_THICKNESS_MM = 2.0
NOTE_SIZE_MM = (96.0, 48.0)  # length, width
NOTE_THICKNESS_MM = 0.2
SEAL_CARD_MM = 70.0  # side of the square card the seal is pressed into
SEAL_RADIUS_MM = 24.0
SEAL_CARD_THICKNESS_MM = 0.3
MOTIF_GRID = 64  # object-frame samples per side of a motif/design field
# relief depth of the embossed originals (their material's `emboss_mm` in synth.MATERIALS),
# whose all-LED appearance a printed copy reproduces
PRINTED_RELIEF_MM = {"coin": 0.15, "seal": 0.2}


def _motif_field(rng, scale_px: float, threshold: float) -> np.ndarray:
    """Plateaus (0..1) of a smoothed random field on the object's own grid."""
    field = ndimage.gaussian_filter(rng.standard_normal((MOTIF_GRID, MOTIF_GRID)), scale_px,
                                    mode="wrap")
    field /= field.std() + 1e-12
    plateaus = (field > threshold).astype(np.float64)
    return ndimage.gaussian_filter(plateaus, 0.8)  # soft edges: ~1 mm slopes on a coin


def instance_params(kind: str, rng) -> dict:
    """Shape parameters of one instance (its own motif or design)."""
    params = {"scale": rng.uniform(0.95, 1.05)}
    if kind == "coin":
        params["motif"] = _motif_field(rng, 3.5, 0.3)
    elif kind == "note":
        params["design"] = _motif_field(rng, 2.5, 0.0)
    elif kind == "seal":
        params["motif"] = _motif_field(rng, 2.0, 0.3)
    else:
        raise ValueError(f"unknown flat object type {kind!r}; choose from {', '.join(FLAT_TYPES)}")
    return params


def _object_frame(x, y, pose: dict):
    """Image coordinates (mm) -> the object's own frame (mm, unscaled)."""
    c, s = math.cos(pose["rotation"]), math.sin(pose["rotation"])
    dx, dy = x - pose["cx"], y - pose["cy"]
    return c * dx + s * dy, -s * dx + c * dy


def _sample(field: np.ndarray, u, v, half_extent_mm: tuple[float, float]) -> np.ndarray:
    """A field on the object grid (covering +-half_extent) sampled at object coords u, v."""
    rows = (0.5 - v / (2 * half_extent_mm[1])) * (MOTIF_GRID - 1)
    cols = (u / (2 * half_extent_mm[0]) + 0.5) * (MOTIF_GRID - 1)
    return ndimage.map_coordinates(field, [rows, cols], order=1, mode="nearest")


def _medallion(field: np.ndarray, u, v, r: float, inner: float, ring: tuple[float, float]):
    """A round motif of radius r (coin face, seal): the field inside `inner` * r and a ring
    between ring[0] * r and ring[1] * r, soft-edged."""
    rho = np.hypot(u, v)
    band = ((rho > ring[0] * r) & (rho < ring[1] * r)).astype(np.float64)
    return np.maximum(_sample(field, u, v, (r, r)) * (rho < inner * r),
                      ndimage.gaussian_filter(band, 0.8))


def shape(kind: str, x, y, shape_params: dict, pose: dict):
    """Height field (mm), object mask, and the motif (0..1; the coin's relief pattern or the
    note's ink design) in image coordinates, for one pose."""
    scale = shape_params["scale"]
    u, v = _object_frame(x, y, pose)
    u, v = u / scale, v / scale
    if kind == "coin":
        mask = np.hypot(u, v) < COIN_RADIUS_MM
        motif = _medallion(shape_params["motif"], u, v, COIN_RADIUS_MM, 0.8, (0.86, 1.0))
        z = np.where(mask, COIN_THICKNESS_MM, 0.0)
        return z, mask, motif * mask
    if kind == "seal":
        half = SEAL_CARD_MM / 2
        mask = (np.abs(u) < half) & (np.abs(v) < half)
        motif = _medallion(shape_params["motif"], u, v, SEAL_RADIUS_MM, 0.82, (0.88, 0.95))
        z = np.where(mask, SEAL_CARD_THICKNESS_MM, 0.0)
        return z, mask, motif * mask
    if kind == "note":
        half = (NOTE_SIZE_MM[0] / 2, NOTE_SIZE_MM[1] / 2)
        mask = (np.abs(u) < half[0]) & (np.abs(v) < half[1])
        design = _sample(shape_params["design"], u, v, half)
        z = np.where(mask, NOTE_THICKNESS_MM, 0.0)
        return z, mask, design * mask
    raise ValueError(f"unknown flat object type {kind!r}; choose from {', '.join(FLAT_TYPES)}")
