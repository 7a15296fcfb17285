"""Synthetic light-stage data: relightable models of real and fake fruit, rendered physically.

Each (sample, pose) is a height field seen by an orthographic camera looking down on the
stage floor, lit in turn by each of the rig's 32 LEDs (8 diffused sites x 4 colours):

- light: point source at the site's position, inverse-square falloff, LED emission lobe
  aimed at the stage centre, per-colour LED power x camera sensitivity;
- shadows: cast by the height field (horizon test along the light's azimuth), softened by
  the diffuser's penumbra;
- reflectance: Lambertian diffuse with spectral albedo (615/515/460/850 nm) and a mottled
  pigment texture whose contrast differs per colour; subsurface scattering as wrapped,
  spatially blurred diffuse shading (per-colour strength and radius); a normalised
  Blinn-Phong specular lobe (white, dielectric) widened by the diffuser;
- micro-relief (peel pores, banana ridges) in the height field, visible under grazing light.

Real and fake fruit of a type differ by small amounts in each of those (spectral albedo in
NIR vs visible, subsurface softening, lobe width, relief depth, pigment contrast per
colour), balanced so that the image with every LED on looks alike, while particular
site/colour combinations reveal the difference. Instances of a class differ in size, shape,
overall albedo and texture; poses differ in placement, rotation and tilt.

`lightstage synth OUT_DIR` (`synth_cli`) writes the capture folder format (docs/CAPTURE_FORMAT.md).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy import ndimage

from . import flat_objects
from .capture_format import write_pose
from .flat_objects import FLAT_TYPES
from .rig import Rig

OBJECT_TYPES = ("green_apple", "red_apple", "grape", "banana", "orange")  # the default set
ALL_OBJECT_TYPES = OBJECT_TYPES + FLAT_TYPES
PLACEMENTS = ("canonical", "free")
VARIANTS = ("fake", "real")
DEFAULT_SIZE = 240
DEFAULT_SAMPLES = 4
DEFAULT_POSES = 5
DEFAULT_SEED = 0
# LED power x camera quantum efficiency per colour (red, green, blue, nir); NIR is weaker
# on a silicon sensor behind a visible/NIR lens.
CHANNEL_POWER = np.array([1.0, 1.1, 0.9, 0.75])
FLOOR_ALBEDO = np.array([0.05, 0.05, 0.05, 0.09])  # black felt, a little brighter in NIR
# Gray level (at the capture setting) of a white Lambertian patch at the stage centre lit by
# one average LED: sets the overall brightness so that all 32 LEDs at the default dimmer put
# a typical fruit (albedo ~0.5) around 500-700 of 1023.
WHITE_LEVEL_PER_LED = 80.0
DIFFUSER_SHININESS = 120.0  # a diffused source caps how sharp a highlight can be
PENUMBRA_MM = 1.5


@dataclass(frozen=True)
class Material:
    """Optical properties of one class; per-colour tuples are (red, green, blue, nir)."""
    albedo: tuple[float, float, float, float]
    pigment_contrast: tuple[float, float, float, float]  # mottled texture depth per colour
    pigment_scale_mm: float
    specular: float  # specular albedo
    shininess: float  # Blinn-Phong exponent: large = narrow lobe
    sss: tuple[float, float, float, float]  # fraction of diffuse light scattered below surface
    sss_radius_mm: tuple[float, float, float, float]
    relief_mm: float  # micro-relief depth
    relief_scale_mm: float
    # flat objects (flat_objects.py): depth of the embossed motif; how strongly a printed
    # copy reproduces the original's all-LED appearance (1 = fully, see _print_factors);
    # how much the printed design darkens each colour
    emboss_mm: float = 0.0
    print_contrast: float = 0.0
    ink_contrast: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def _m(**kw) -> Material:
    return Material(**kw)


# Real fruit: high NIR reflectance from cell structure, strong red/NIR subsurface scattering,
# waxy broad highlights, pigment texture that fades in NIR. Fakes (painted foam/plastic):
# paint pigment also shows in NIR, little subsurface scattering, narrower highlights,
# shallower or coarser moulded relief. Visible albedo is nudged so the all-LED sum matches.
MATERIALS: dict[str, dict[str, Material]] = {
    "green_apple": {
        "real": _m(albedo=(0.30, 0.50, 0.12, 0.70), pigment_contrast=(0.14, 0.14, 0.16, 0.00),
                   pigment_scale_mm=4.0, specular=0.05, shininess=25,
                   sss=(0.55, 0.45, 0.25, 0.65), sss_radius_mm=(3.0, 2.5, 1.5, 4.0),
                   relief_mm=0.05, relief_scale_mm=3.0),
        "fake": _m(albedo=(0.33, 0.54, 0.13, 0.62), pigment_contrast=(0.05, 0.05, 0.06, 0.25),
                   pigment_scale_mm=4.0, specular=0.06, shininess=60,
                   sss=(0.15, 0.15, 0.10, 0.15), sss_radius_mm=(1.0, 1.0, 0.8, 1.0),
                   relief_mm=0.20, relief_scale_mm=4.0),
    },
    "red_apple": {
        "real": _m(albedo=(0.55, 0.12, 0.10, 0.72), pigment_contrast=(0.10, 0.40, 0.35, 0.00),
                   pigment_scale_mm=3.0, specular=0.06, shininess=30,
                   sss=(0.60, 0.30, 0.25, 0.65), sss_radius_mm=(3.5, 2.0, 1.5, 4.0),
                   relief_mm=0.05, relief_scale_mm=3.0),
        "fake": _m(albedo=(0.57, 0.13, 0.11, 0.66), pigment_contrast=(0.12, 0.22, 0.20, 0.35),
                   pigment_scale_mm=3.0, specular=0.07, shininess=70,
                   sss=(0.20, 0.15, 0.15, 0.20), sss_radius_mm=(1.0, 0.8, 0.8, 1.0),
                   relief_mm=0.05, relief_scale_mm=3.0),
    },
    "grape": {
        "real": _m(albedo=(0.16, 0.26, 0.10, 0.60), pigment_contrast=(0.05, 0.05, 0.05, 0.00),
                   pigment_scale_mm=3.0, specular=0.03, shininess=12,
                   sss=(0.70, 0.65, 0.50, 0.80), sss_radius_mm=(3.0, 2.5, 2.0, 4.0),
                   relief_mm=0.02, relief_scale_mm=2.0),
        "fake": _m(albedo=(0.18, 0.28, 0.11, 0.52), pigment_contrast=(0.03, 0.03, 0.03, 0.20),
                   pigment_scale_mm=3.0, specular=0.09, shininess=110,
                   sss=(0.20, 0.20, 0.15, 0.20), sss_radius_mm=(1.0, 1.0, 0.8, 1.0),
                   relief_mm=0.02, relief_scale_mm=2.0),
    },
    "banana": {
        "real": _m(albedo=(0.62, 0.55, 0.10, 0.74), pigment_contrast=(0.25, 0.30, 0.14, 0.00),
                   pigment_scale_mm=3.0, specular=0.03, shininess=20,
                   sss=(0.35, 0.30, 0.20, 0.45), sss_radius_mm=(2.0, 1.5, 1.0, 2.5),
                   relief_mm=0.08, relief_scale_mm=3.0),
        "fake": _m(albedo=(0.64, 0.57, 0.11, 0.68), pigment_contrast=(0.12, 0.14, 0.07, 0.30),
                   pigment_scale_mm=3.0, specular=0.05, shininess=45,
                   sss=(0.10, 0.10, 0.08, 0.10), sss_radius_mm=(0.6, 0.6, 0.5, 0.6),
                   relief_mm=0.25, relief_scale_mm=4.0),
    },
    "orange": {
        "real": _m(albedo=(0.66, 0.36, 0.06, 0.74), pigment_contrast=(0.06, 0.08, 0.06, 0.00),
                   pigment_scale_mm=4.0, specular=0.06, shininess=50,
                   sss=(0.50, 0.40, 0.30, 0.60), sss_radius_mm=(2.5, 2.0, 1.5, 3.0),
                   relief_mm=0.35, relief_scale_mm=2.0),
        "fake": _m(albedo=(0.68, 0.37, 0.07, 0.68), pigment_contrast=(0.03, 0.04, 0.03, 0.18),
                   pigment_scale_mm=4.0, specular=0.05, shininess=40,
                   sss=(0.12, 0.12, 0.10, 0.12), sss_radius_mm=(0.8, 0.8, 0.6, 0.8),
                   relief_mm=0.12, relief_scale_mm=3.0),
    },
    # Flat objects: "real" and "fake" share every optical property except the one the
    # light must reveal. Coin: embossed brass vs a flat print of it on glossy card.
    # Note: inks transparent in NIR (real) vs inks that also absorb NIR (copy).
    "coin": {
        "real": _m(albedo=(0.70, 0.55, 0.30, 0.78), pigment_contrast=(0.05, 0.05, 0.05, 0.05),
                   pigment_scale_mm=2.0, specular=0.08, shininess=40,
                   sss=(0.0, 0.0, 0.0, 0.0), sss_radius_mm=(0.5, 0.5, 0.5, 0.5),
                   relief_mm=0.02, relief_scale_mm=1.0,
                   emboss_mm=flat_objects.PRINTED_RELIEF_MM["coin"]),
        "fake": _m(albedo=(0.70, 0.55, 0.30, 0.78), pigment_contrast=(0.05, 0.05, 0.05, 0.05),
                   pigment_scale_mm=2.0, specular=0.08, shininess=40,
                   sss=(0.0, 0.0, 0.0, 0.0), sss_radius_mm=(0.5, 0.5, 0.5, 0.5),
                   relief_mm=0.02, relief_scale_mm=1.0, print_contrast=1.0),
    },
    "note": {
        "real": _m(albedo=(0.80, 0.80, 0.76, 0.86), pigment_contrast=(0.04, 0.04, 0.04, 0.04),
                   pigment_scale_mm=1.5, specular=0.02, shininess=10,
                   sss=(0.2, 0.2, 0.2, 0.2), sss_radius_mm=(0.5, 0.5, 0.5, 0.5),
                   relief_mm=0.01, relief_scale_mm=1.0, ink_contrast=(0.50, 0.50, 0.50, 0.0)),
        "fake": _m(albedo=(0.80, 0.80, 0.76, 0.86), pigment_contrast=(0.04, 0.04, 0.04, 0.04),
                   pigment_scale_mm=1.5, specular=0.02, shininess=10,
                   sss=(0.2, 0.2, 0.2, 0.2), sss_radius_mm=(0.5, 0.5, 0.5, 0.5),
                   relief_mm=0.01, relief_scale_mm=1.0, ink_contrast=(0.45, 0.45, 0.45, 0.40)),
    },
    # Seal: the same card and inks; a design pressed into relief (real) vs a flat print.
    "seal": {
        "real": _m(albedo=(0.82, 0.80, 0.74, 0.86), pigment_contrast=(0.04, 0.04, 0.04, 0.04),
                   pigment_scale_mm=1.5, specular=0.01, shininess=8,
                   sss=(0.2, 0.2, 0.2, 0.2), sss_radius_mm=(0.5, 0.5, 0.5, 0.5),
                   relief_mm=0.005, relief_scale_mm=1.0,
                   emboss_mm=flat_objects.PRINTED_RELIEF_MM["seal"],
                   ink_contrast=(0.30, 0.35, 0.40, 0.30)),
        "fake": _m(albedo=(0.82, 0.80, 0.74, 0.86), pigment_contrast=(0.04, 0.04, 0.04, 0.04),
                   pigment_scale_mm=1.5, specular=0.01, shininess=8,
                   sss=(0.2, 0.2, 0.2, 0.2), sss_radius_mm=(0.5, 0.5, 0.5, 0.5),
                   relief_mm=0.005, relief_scale_mm=1.0, print_contrast=1.0,
                   ink_contrast=(0.30, 0.35, 0.40, 0.30)),
    },
}


# the physical range of each material property: fractions in 0..1, lengths and the
# Blinn-Phong exponent >= 0 (a fake blended past the tabled one must stay a material)
FRACTION_FIELDS = ("albedo", "pigment_contrast", "specular", "sss", "print_contrast",
                   "ink_contrast")
MAX_STRENGTH = 10.0
# peak memory of rendering one pose, per pixel (measured: ~1.0 kB at 120 and 240 px, any type)
RENDER_BYTES_PER_PIXEL = 1100


def check_strength(strength: float, object_types) -> None:
    """Refuse a --strength that gives some class a material no object has (a reflectance
    below 0 or above 1, a negative length): ValueError naming the class and property."""
    if not (math.isfinite(strength) and 0 <= strength <= MAX_STRENGTH):
        raise ValueError(f"strength must be 0 .. {MAX_STRENGTH:g} (0 = identical real and fake "
                         f"materials, 1 = as tabled), got {strength}")
    for kind in object_types:
        materials = MATERIALS[kind]
        blended = blend_materials(materials["real"], materials["fake"], strength)
        for name in Material.__dataclass_fields__:
            values = getattr(blended, name)
            values = values if isinstance(values, tuple) else (values,)
            hi = 1.0 if name in FRACTION_FIELDS else math.inf
            if not all(0.0 <= v <= hi for v in values):
                raise ValueError(f"strength {strength:g} makes the fake {kind}'s {name} "
                                 f"{[round(v, 3) for v in values]}, outside "
                                 f"{'0 .. 1' if hi == 1 else '>= 0'}; use a smaller strength")


def available_memory_bytes() -> int | None:
    """MemAvailable of /proc/meminfo (None where there is none)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_render_memory(image_size: int, n_jobs: int, available: int | None = None) -> None:
    """Refuse an image size whose rendering (n_jobs poses at once) needs more memory than
    this machine has available, with the estimate and the largest size that fits."""
    available = available_memory_bytes() if available is None else available
    if available is None:
        return
    n_jobs = max(1, int(n_jobs))
    need = RENDER_BYTES_PER_PIXEL * image_size ** 2 * n_jobs
    if need > available:
        fits = int(math.sqrt(available / (RENDER_BYTES_PER_PIXEL * n_jobs)))
        raise ValueError(f"size {image_size} px needs about {need / 2**30:.3g} GiB of memory to "
                         f"render ({RENDER_BYTES_PER_PIXEL} bytes per pixel per pose x {n_jobs} "
                         f"parallel job(s)); {available / 2**30:.3g} GiB are available: use a "
                         f"size up to {fits} px (or fewer --jobs)")


def blend_materials(real: Material, fake: Material, strength: float) -> Material:
    """The fake material moved toward the real one: strength 1 = as tabled, 0 = identical."""
    out = {}
    for name in Material.__dataclass_fields__:
        a, b = getattr(real, name), getattr(fake, name)
        if isinstance(a, tuple):
            out[name] = tuple(x + strength * (y - x) for x, y in zip(a, b))
        else:
            out[name] = a + strength * (b - a)
    return Material(**out)


# ---- geometry ---------------------------------------------------------------------------
def _grid(size: int, fov_mm: float):
    px = fov_mm / size
    c = (np.arange(size) - (size - 1) / 2) * px
    x, y = np.meshgrid(c, -c)  # rows go down the image, y goes up
    return x, y, px


def _smooth_noise(rng, shape, scale_px: float) -> np.ndarray:
    """Zero-mean, unit-std Gaussian random field with correlation length `scale_px`."""
    field = ndimage.gaussian_filter(rng.standard_normal(shape), max(scale_px, 0.3), mode="wrap")
    return field / (field.std() + 1e-12)


def _dome(x, y, cx, cy, r, squash=1.0):
    """Upper surface of a sphere of radius r resting on the floor (height field, mm)."""
    d2 = (x - cx) ** 2 + (y - cy) ** 2
    inside = d2 < r * r
    z = np.where(inside, r + squash * np.sqrt(np.maximum(r * r - d2, 0)), 0.0)
    return z, inside


def _shape(kind: str, x, y, shape_params: dict, pose: dict):
    """Height field (mm) and object mask for one object type in one pose."""
    cx, cy, rot, tilt = pose["cx"], pose["cy"], pose["rotation"], pose["tilt"]
    scale = shape_params["scale"]
    if kind in ("green_apple", "red_apple", "orange"):
        r = (40.0 if kind == "orange" else 33.0) * scale
        squash = shape_params["squash"]
        z, mask = _dome(x, y, cx, cy, r, squash)
        if kind != "orange":  # stem cavity, off-centre when the apple is tilted
            dx, dy = r * math.sin(tilt) * math.cos(rot), r * math.sin(tilt) * math.sin(rot)
            cav = np.exp(-((x - cx - dx) ** 2 + (y - cy - dy) ** 2) / (2 * (0.22 * r) ** 2))
            z = z - mask * 9.0 * scale * cav
        return z, mask
    if kind == "grape":
        z = np.zeros_like(x)
        mask = np.zeros(x.shape, bool)
        for gx, gy, gr in shape_params["grapes"]:
            px_ = cx + gx * math.cos(rot) - gy * math.sin(rot)
            py_ = cy + gx * math.sin(rot) + gy * math.cos(rot)
            zg, mg = _dome(x, y, px_, py_, gr * scale, 0.95)
            z = np.maximum(z, zg)
            mask |= mg
        return z, mask
    if kind == "banana":
        # a tube along a circular arc, tapered at the ends, with five longitudinal ridges
        bend = shape_params["bend_mm"]
        half_angle = shape_params["length_mm"] * scale / 2 / bend
        ox, oy = cx - bend * math.cos(rot), cy - bend * math.sin(rot)
        dx, dy = x - ox, y - oy
        rho = np.hypot(dx, dy)
        phi = np.angle(np.exp(1j * (np.arctan2(dy, dx) - rot)))
        t = np.clip(phi / half_angle, -1.0, 1.0)  # -1..1 along the banana
        radius = 16.0 * scale * np.sqrt(np.clip(1 - t ** 8, 0, 1))
        d = rho - bend
        inside = (np.abs(phi) < half_angle) & (np.abs(d) < radius)
        psi = np.arcsin(np.clip(d / np.maximum(radius, 1e-6), -1, 1))
        ridges = 1 - shape_params["ridge_depth"] * (0.5 - 0.5 * np.cos(5 * psi))
        z = np.where(inside, radius * (1 + np.cos(psi) * ridges), 0.0)
        return z, inside
    raise ValueError(f"unknown object type {kind!r}; choose from {', '.join(OBJECT_TYPES)}")


def _instance_shape(kind: str, rng) -> dict:
    params = {"scale": rng.uniform(0.92, 1.08), "squash": rng.uniform(0.85, 1.0)}
    if kind == "grape":
        grapes = []
        for _ in range(int(rng.integers(9, 15))):
            for _attempt in range(40):
                gx, gy = rng.normal(0, [16, 11])
                gr = rng.uniform(8.0, 10.5)
                if all(math.hypot(gx - a, gy - b) > 0.8 * (gr + c) for a, b, c in grapes):
                    grapes.append((gx, gy, gr))
                    break
        params["grapes"] = grapes
    if kind == "banana":
        params.update(bend_mm=rng.uniform(90, 140), length_mm=rng.uniform(120, 145),
                      ridge_depth=rng.uniform(0.04, 0.08))
    return params


# ---- light transport ---------------------------------------------------------------------
def _normals(z, px):
    gy, gx = np.gradient(z, px)
    gy = -gy  # rows go down, y goes up
    norm = np.sqrt(gx * gx + gy * gy + 1.0)
    return -gx / norm, -gy / norm, 1.0 / norm


def _shadow(z, azimuth: float, tan_elevation: float, px: float) -> np.ndarray:
    """Visibility (0..1) of a light at `azimuth` (rad) and elevation, from the height field.

    Rotate so the light lies along +columns; a point is shadowed when some point nearer
    the light rises above the ray to it: max_{a'>a} (z(a') - a' tan) > z(a) - a tan.
    """
    size = z.shape
    deg = -math.degrees(azimuth)
    rz = ndimage.rotate(z, deg, reshape=True, order=1, mode="constant", cval=0.0)
    cols = np.arange(rz.shape[1]) * px * tan_elevation
    g = rz - cols[None, :]
    horizon = np.maximum.accumulate(g[:, ::-1], axis=1)[:, ::-1]
    horizon = np.concatenate([horizon[:, 1:], np.full((rz.shape[0], 1), -np.inf)], axis=1)
    vis = np.clip(1.0 - (horizon - g) / PENUMBRA_MM, 0.0, 1.0)
    back = ndimage.rotate(vis, -deg, reshape=True, order=1, mode="nearest")
    r0 = (back.shape[0] - size[0]) // 2
    c0 = (back.shape[1] - size[1]) // 2
    return back[r0:r0 + size[0], c0:c0 + size[1]]


def _shadows(z, sites, px) -> np.ndarray:
    """Visibility of every site; at half resolution for large images (the diffuser's
    penumbra is wider than two pixels, and the rotations are the costliest step)."""
    step = 2 if min(z.shape) >= 120 else 1
    if step > 1 and z.shape[0] % step == 0 and z.shape[1] % step == 0:
        # highest point of each 2 x 2 block: thin occluders still cast their shadow
        coarse = z.reshape(z.shape[0] // step, step, z.shape[1] // step, step).max(axis=(1, 3))
    else:
        coarse = z[::step, ::step]
    out = np.empty((len(sites),) + z.shape)
    for s, (sx, sy, sz) in enumerate(sites):
        vis = _shadow(coarse, math.atan2(sy, sx), sz / math.hypot(sx, sy), px * step)
        if step > 1:
            vis = ndimage.zoom(vis, (z.shape[0] / vis.shape[0], z.shape[1] / vis.shape[1]),
                               order=1, mode="nearest", grid_mode=True)
        out[s] = vis
    return out


def _masked_blur(image, mask_f, sigma_px, mask_blur_cache: dict):
    """Blur confined to the object (subsurface light does not leak onto the floor)."""
    if sigma_px < 0.3:
        return image
    key = round(sigma_px, 3)
    if key not in mask_blur_cache:
        mask_blur_cache[key] = ndimage.gaussian_filter(mask_f, sigma_px) + 1e-6
    return ndimage.gaussian_filter(image * mask_f, sigma_px) / mask_blur_cache[key]


def _site_shading(z, mask_f, material: Material, x, y, px: float, sites):
    """How each site lights a height field, before albedo: per site the irradiance
    ``(S, H, W)`` (relative to the average site's at the centre), per colour and site the
    diffuse factor ``(4, S, H, W)`` (Lambert with cast shadows, part of it scattered below
    the surface) and per site the specular term ``(S, H, W)``. A pixel's level under site s in
    colour c is then ``WHITE * power[c] * irradiance[s] * (albedo[c] * diffuse[c, s] +
    specular[s])``."""
    nx, ny, nz = _normals(z, px)
    shininess = 1.0 / (1.0 / material.shininess + 1.0 / DIFFUSER_SHININESS)
    spec_norm = (shininess + 8.0) / 8.0
    blur_cache: dict = {}
    # reference: a flat white patch at the centre lit by the average site
    ref = np.mean([s[2] / np.linalg.norm(s) ** 3 for s in sites])
    shadows = _shadows(z, sites, px)
    irradiance = np.empty((len(sites),) + z.shape)
    diffuse = np.empty((4, len(sites)) + z.shape)
    specular = np.empty((len(sites),) + z.shape)
    for s, (sx, sy, sz) in enumerate(sites):
        lx, ly, lz = sx - x, sy - y, sz - z
        d = np.sqrt(lx * lx + ly * ly + lz * lz)
        lx, ly, lz = lx / d, ly / d, lz / d
        # LED lobe aimed at the stage centre (cos^2 falloff off-axis) and inverse-square law
        axis = -np.array([sx, sy, sz]) / math.sqrt(sx * sx + sy * sy + sz * sz)
        lobe = np.clip(-(lx * axis[0] + ly * axis[1] + lz * axis[2]), 0, 1) ** 2
        irradiance[s] = lobe / (d * d) / ref
        vis = shadows[s]
        ndotl = nx * lx + ny * ly + nz * lz
        lambert = np.clip(ndotl, 0, None) * vis
        wrap = np.clip((ndotl + 0.35) / 1.35, 0, None) * (0.4 + 0.6 * vis)
        hx, hy, hz = lx, ly, lz + 1.0
        hn = np.sqrt(hx * hx + hy * hy + hz * hz)
        ndoth = np.clip((nx * hx + ny * hy + nz * hz) / hn, 0, 1)
        specular[s] = mask_f * material.specular * spec_norm * ndoth ** shininess * lambert
        for c in range(4):
            diffuse_sss = _masked_blur(wrap, mask_f, material.sss_radius_mm[c] / px, blur_cache)
            k = material.sss[c] * mask_f
            diffuse[c, s] = (1 - k) * lambert + k * diffuse_sss
    return irradiance, diffuse, specular


def _all_led_level(albedo_c, irradiance, diffuse_c, specular):
    """Level (before the white level and colour power) of one colour with every site on."""
    return (irradiance * (albedo_c * diffuse_c + specular)).sum(axis=0)


def _print_factors(kind: str, material: Material, albedo, mask_f, z_flat, motif, shading, x, y,
                   px: float, sites):
    """Albedo factors (4, H, W) of a flat copy printed from a photograph of the embossed
    original under every LED: where the copy's print is full strength (print_contrast 1) the
    flat copy returns, with every LED on, what the original with a PRINTED_RELIEF_MM[kind]
    relief of the same motif returns, pixel for pixel (its shading, shadows and glints), so
    the two are told apart only by light that does not come from all sides at once."""
    z_ref = z_flat + flat_objects.PRINTED_RELIEF_MM[kind] * motif
    irr_ref, diff_ref, spec_ref = _site_shading(z_ref, mask_f, material, x, y, px, sites)
    irradiance, diffuse, specular = shading
    factors = np.ones((4,) + z_flat.shape)
    inside = mask_f > 0.5
    copy_gloss = (irradiance * specular).sum(axis=0)  # the copy's own gloss, every LED on
    for c in range(4):
        target = _all_led_level(albedo[c], irr_ref, diff_ref[c], spec_ref)
        copy_matte = albedo[c] * (irradiance * diffuse[c]).sum(axis=0)
        exact = (target - copy_gloss) / np.maximum(copy_matte, 1e-9)
        # ink darkens, paper whitens no further than its own white
        exact = np.clip(exact, 0.0, 1.0 / max(material.albedo[c], 1e-6))
        factors[c] = np.where(inside, 1.0 + material.print_contrast * (exact - 1.0), 1.0)
    return factors


def render_pose(kind: str, material: Material, shape_params: dict, pose: dict, rig: Rig,
                rng: np.random.Generator, model_noise: float = 0.0) -> np.ndarray:
    """The 32 single-LED images ``(4, sites, H, W)`` of one pose, in gray levels."""
    size = rig.image_size[0]
    x, y, px = _grid(size, rig.field_of_view_mm)
    flat = kind in FLAT_TYPES
    if flat:
        z_obj, mask, motif = flat_objects.shape(kind, x, y, shape_params, pose)
        z_flat = z_obj
        z_obj = z_obj + material.emboss_mm * motif
    else:
        z_obj, mask = _shape(kind, x, y, shape_params, pose)
    mask_f = mask.astype(np.float64)
    # micro-relief: pores are dimples (negative), ridges for the banana come from the shape
    relief = _smooth_noise(rng, x.shape, material.relief_scale_mm / px)
    relief = -np.abs(relief) if kind in ("orange", "grape") else relief
    micro = mask_f * material.relief_mm * relief
    z = z_obj + micro
    # pigment: one mottle field, contrast per colour (multiplicative on albedo)
    mottle = _smooth_noise(rng, x.shape, material.pigment_scale_mm / px)
    if kind == "red_apple":  # streaks run along meridians: stretch the mottle radially
        streak = _smooth_noise(rng, (x.shape[0], x.shape[1]), 1.0)
        ang = np.arctan2(y - pose["cy"], x - pose["cx"])
        mottle = 0.5 * mottle + 0.5 * np.cos(7 * ang + 2 * streak)
    tint = shape_params["tint"]  # instance albedo variation
    albedo = np.empty((4,) + x.shape)
    for c in range(4):
        obj = material.albedo[c] * tint[c] * np.clip(1 + material.pigment_contrast[c] * mottle,
                                                     0.05, None)
        if flat:  # the printed design darkens each colour by its ink's contrast
            obj = obj * (1.0 - material.ink_contrast[c] * motif)
        albedo[c] = mask_f * obj + (1 - mask_f) * FLOOR_ALBEDO[c]
    sites = rig.site_positions_mm()
    shading = _site_shading(z, mask_f, material, x, y, px, sites)
    if flat and material.print_contrast:
        albedo = albedo * _print_factors(kind, material, albedo, mask_f, z_flat + micro, motif,
                                         shading, x, y, px, sites)
    irradiance, diffuse, specular = shading
    out = np.empty((4, len(sites), size, size), np.float32)
    for c in range(4):
        out[c] = WHITE_LEVEL_PER_LED * CHANNEL_POWER[c] * irradiance * (
            albedo[c] * diffuse[c] + specular)
    if model_noise > 0:  # residual noise of the averaged capture frames
        out += rng.normal(0, model_noise, out.shape).astype(np.float32)
    return np.clip(out, 0, rig.max_level, out=out)


# ---- dataset ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SampleJob:
    class_name: str
    kind: str
    variant: str
    instance: int
    pose: int
    seed: tuple


def _instance_params(kind: str, seed: tuple) -> dict:
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    params = (flat_objects.instance_params(kind, rng) if kind in FLAT_TYPES
              else _instance_shape(kind, rng))
    overall = rng.uniform(0.9, 1.1)  # overall albedo varies between instances...
    params["tint"] = tuple(overall * rng.uniform(0.95, 1.05, 4))  # ...and a little per colour
    return params


FREE_SHIFT_MM = 25.0  # free placement: centre anywhere within +-25 mm of the stage centre
FREE_SCALE = (0.9, 1.1)  # free placement: apparent size change (distance, object size)


def _pose_params(seed: tuple, placement: str = "canonical") -> dict:
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    if placement == "canonical":
        # objects are placed roughly the same way up on the stage: +-35 deg about a
        # canonical orientation, +-8 mm off centre, tilted up to ~30 deg
        return {"cx": rng.uniform(-8, 8), "cy": rng.uniform(-8, 8),
                "rotation": rng.uniform(-0.6, 0.6), "tilt": rng.uniform(0, 0.5)}
    if placement == "free":
        # placed any way: any in-plane rotation, anywhere near the centre, a little larger
        # or smaller
        return {"cx": rng.uniform(-FREE_SHIFT_MM, FREE_SHIFT_MM),
                "cy": rng.uniform(-FREE_SHIFT_MM, FREE_SHIFT_MM),
                "rotation": rng.uniform(-math.pi, math.pi), "tilt": rng.uniform(0, 0.5),
                "scale": rng.uniform(*FREE_SCALE)}
    raise ValueError(f"unknown placement {placement!r}; choose from {', '.join(PLACEMENTS)}")


def _instance_seed(job: SampleJob) -> tuple:
    """Seed of the physical sample a job shows: (seed, type, variant, sample). A fake flat
    object is a copy of the real sample with the same number (a forger copies a specimen):
    it shares that sample's design, size and tint, so the two classes do not differ by
    which designs they hold, only by relief or ink."""
    seed = job.seed[:-1]
    if job.kind in FLAT_TYPES:
        seed = seed[:2] + (VARIANTS.index("real"),) + seed[3:]
    return seed


def render_job(job: SampleJob, rig: Rig, strength: float, model_noise: float,
               placement: str = "canonical") -> np.ndarray:
    materials = MATERIALS[job.kind]
    material = materials["real"] if job.variant == "real" else blend_materials(
        materials["real"], materials["fake"], strength)
    shape = _instance_params(job.kind, _instance_seed(job))
    pose = _pose_params(job.seed + (1,), placement)
    if "scale" in pose:
        shape = {**shape, "scale": shape["scale"] * pose["scale"]}
    rng = np.random.default_rng(np.random.SeedSequence(job.seed + (2,)))
    return render_pose(job.kind, material, shape, pose, rig, rng, model_noise)


def plan(object_types, n_samples_per_class: int, n_poses: int, seed: int) -> list[SampleJob]:
    jobs = []
    for t_index, kind in enumerate(object_types):
        if kind not in MATERIALS:
            raise ValueError(f"unknown object type {kind!r}; choose from "
                             f"{', '.join(ALL_OBJECT_TYPES)}")
        for v_index, variant in enumerate(VARIANTS):
            for inst in range(n_samples_per_class):
                for pose in range(n_poses):
                    seed_key = (int(seed), ALL_OBJECT_TYPES.index(kind), v_index, inst, pose)
                    jobs.append(SampleJob(f"{kind}-{variant}", kind, variant, inst, pose,
                                          seed_key))
    return jobs


def _write_job(out_dir: Path, job: SampleJob, rig: Rig, strength: float, model_noise: float,
               compress_level: int, placement: str = "canonical") -> None:
    model = render_job(job, rig, strength, model_noise, placement)
    write_pose(out_dir / job.class_name / f"s{job.instance}" / f"p{job.pose:02d}", model,
               rig.bit_depth, compress_level)


def capture_rig(image_size: int) -> Rig:
    """The rig a synthetic capture is stated at: gray levels at the noise model's reference
    setting (15 dB, 30 ms); the simulated capture averaged 64 frames, hence the small
    `model_noise`."""
    return replace(Rig.paper_default(image_size), frames_averaged=64, exposure_us=30000.0,
                   gain_db=15.0)


def generate(out_dir, image_size: int = DEFAULT_SIZE, n_samples_per_class: int = DEFAULT_SAMPLES,
             n_poses: int = DEFAULT_POSES, seed: int = DEFAULT_SEED,
             object_types=OBJECT_TYPES, n_jobs: int = 2, strength: float = 1.0,
             model_noise: float = 0.1, compress_level: int = 2, progress=None,
             overwrite: bool = False, placement: str = "canonical") -> Path:
    """Write the synthetic dataset as a capture folder; returns its path.

    Every class gets `n_samples_per_class` instances x `n_poses` poses (20 pose indices per
    class by default). `strength` scales the real/fake material differences (1 = tabled).
    `model_noise` is the residual noise (std, gray levels) of the averaged model captures.
    `placement`: "canonical" (+-35 deg about one orientation, +-8 mm off centre; the
    default) or "free" (any in-plane rotation, +-25 mm, scale 0.9..1.1).
    Deterministic for a seed, whatever `n_jobs`. A non-empty `out_dir` is refused unless
    `overwrite` (files of the same names are then replaced; other folders are left alone
    and would be loaded as extra classes, so prefer a fresh folder).
    """
    from joblib import Parallel, delayed

    if image_size < 16:
        raise ValueError(f"image_size must be >= 16 pixels, got {image_size}")
    if n_samples_per_class < 1 or n_poses < 1:
        raise ValueError("need at least one sample and one pose per class")
    if placement not in PLACEMENTS:
        raise ValueError(f"unknown placement {placement!r}; choose from {', '.join(PLACEMENTS)}")
    object_types = tuple(object_types)
    check_strength(strength, object_types)
    check_render_memory(image_size, n_jobs if n_jobs > 0 else (os.cpu_count() or 1))
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()) and not overwrite:
        raise ValueError(f"{out_dir} is not empty; choose a new folder or pass overwrite "
                         "(--force)")
    out_dir.mkdir(parents=True, exist_ok=True)
    rig = capture_rig(image_size)
    rig.save_yaml(out_dir / "rig.yaml")
    jobs = plan(object_types, n_samples_per_class, n_poses, seed)
    runner = Parallel(n_jobs=n_jobs, return_as="generator", batch_size=4)
    tasks = (delayed(_write_job)(out_dir, job, rig, strength, model_noise, compress_level,
                                 placement)
             for job in jobs)
    for done, _ in enumerate(runner(tasks), start=1):
        if progress is not None:
            progress(done, len(jobs))
    return out_dir
