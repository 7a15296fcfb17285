"""Materials of the synthetic objects: the real and fake class of each type, and blending.

A `Material` holds the optical properties the renderer (`fruit_render`, `flat_objects`)
uses, per colour channel (red, green, blue, NIR: 615/515/460/850 nm) where they depend on
wavelength. `MATERIALS` tables the real and the fake material of every object type; the fake
is moved toward the real one by `blend_materials` (``--strength``: 0 = identical, 1 = as
tabled).
"""
from __future__ import annotations

from dataclasses import dataclass

from . import flat_objects

__all__ = ["FRACTION_FIELDS", "MATERIALS", "MAX_STRENGTH", "Material", "blend_materials"]


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
