"""Rendering one pose of a synthetic object: its height field lit by each of the 32 LEDs.

Geometry (the fruit's shapes, micro-relief, placement) and light transport: a point source
per site with inverse-square falloff and an emission lobe aimed at the stage centre; cast
shadows by a horizon test along the light's azimuth, softened by the diffuser's penumbra;
Lambertian diffuse with spectral albedo and mottled pigment, subsurface scattering as wrapped,
blurred diffuse shading, and a normalised Blinn-Phong lobe widened by the diffuser. Flat
objects (coin, note, seal) take their height field and motif from `flat_objects`.
`render_pose` is the entry point; `synth` plans and writes whole datasets with it.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from . import flat_objects
from .flat_objects import FLAT_TYPES
from .materials import Material
from .rig import Rig

OBJECT_TYPES = ("green_apple", "red_apple", "grape", "banana", "orange")  # the fruit shapes

__all__ = ["OBJECT_TYPES", "CHANNEL_POWER", "FLOOR_ALBEDO", "WHITE_LEVEL_PER_LED", "DIFFUSER_SHININESS",
           "PENUMBRA_MM", "render_pose", "instance_shape"]

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


def instance_shape(kind: str, rng) -> dict:
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
