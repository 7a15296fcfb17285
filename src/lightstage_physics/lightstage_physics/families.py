"""Procedural object families: two classes of physical samples drawn from one seed.

A family is one object shape and two materials that differ in a few optical properties, the
difference scaled by a strength. It turns "does a method hold on objects it was not tuned
on?" into a distribution over families (benchmarks/families_benchmark.py). Everything is
rendered by `synth.render_pose` (the synthetic stage's shapes, shading, shadows, subsurface
scattering, specular lobe, relief and inks); this module only draws what to render.

What one family seed draws (`draw_family`; stream `FAMILY_STREAM`):

- shape: one of the synthetic stage's shape models (`synth.ALL_OBJECT_TYPES`: domes with a
  stem cavity, a dome, a grape bunch, a banana, a coin, a note, a sealed card), scaled by
  `SCALE_RANGE`; both classes share it (the outline never tells the classes apart);
- base material (`synth.Material`): albedo per colour (red, green, blue, NIR) in
  `ALBEDO_RANGE`; pigment mottle contrast per colour up to 0.2 at 1.5-5 mm; specular albedo
  0.01-0.08 and Blinn-Phong exponent 8-120 (log-uniform); subsurface fraction per colour up
  to 0.6 with radius 0.5-4 mm; micro-relief 0.01-0.15 mm deep at 1-4 mm; on the flat shapes an
  embossed motif up to 0.2 mm deep and ink contrast per colour up to 0.5;
- cues: 1 to `MAX_CUES` of `CUES` (the flat-only ones on flat shapes), each a signed
  difference of random size (half to full of its `CUE_SCALE`):
  ``albedo`` per-colour albedo, ``nir`` the NIR albedo alone (both balanced so that the
  power-weighted mean albedo, what all LEDs on see, is the same), ``gloss`` specular albedo
  and exponent, ``relief`` micro-relief depth, ``sss`` subsurface fraction per colour,
  ``pigment`` mottle contrast per colour, ``ink`` ink contrast per colour, ``emboss`` motif
  depth;
- the two class materials: base -/+ strength / 2 x the difference (class ``a`` / ``b``),
  clipped to physical ranges; at strength 0 they are the same material.

Each physical sample (`sample_draw`, seeded by family, class index and sample number) has
its own variation, drawn the same way for either class: its own shape instance (size,
squash, grape layout, banana bend, coin/seal motif, note design), its material jittered by
`sample_spread` (albedo per colour x (1 +- spread), relief, specular and mottle x exp(N(0,
2 spread)), subsurface +- spread), an overall and per-colour tint (0.9-1.1 x 0.95-1.05), and a
gain on its images (1 +- `GAIN_SPREAD`: how brightly the stage saw it). Each pose is a free
placement (`synth._pose_params(..., 'free')`: any in-plane rotation, +-25 mm, a tilt, scale
0.9-1.1) with its own relief and mottle draws. No draw is shared across classes and nothing
is normalised per class: the class index enters only through the material, so a family at
strength 0 renders two classes of the same distribution (a classifier must sit at chance).

`generate_family` writes it as a capture folder (docs/CAPTURE_FORMAT.md): classes
``family-a`` and ``family-b`` (one object type, ``family``), ``s<sample>/p<pose>``, and the
family's description in ``family.json``. `lightstage synth OUT --family SEED` is its CLI.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from . import flat_objects, synth
from .capture_format import write_pose
from .flat_objects import FLAT_TYPES
from .synth import CHANNEL_POWER, Material

FAMILY_STREAM = 4217  # seed-sequence tag of every family draw (distinct from synth's seeds)
CLASS_NAMES = ("family-a", "family-b")
CUES = ("albedo", "nir", "gloss", "relief", "sss", "pigment", "ink", "emboss")
FLAT_ONLY_CUES = ("ink", "emboss")
MAX_CUES = 3
# size of each cue's difference at strength 1 (albedo-like fractions; relief and exponent
# as log factors)
CUE_SCALE = {"albedo": 0.12, "nir": 0.2, "gloss": 0.06, "relief": 1.2, "sss": 0.4,
             "pigment": 0.15, "ink": 0.3, "emboss": 0.15}
ALBEDO_RANGE = (0.15, 0.75)
SCALE_RANGE = (0.8, 1.15)
DEFAULT_SAMPLE_SPREAD = 0.05
GAIN_SPREAD = 0.1
MAX_STRENGTH = 10.0
FRACTION_FIELDS = synth.FRACTION_FIELDS


@dataclass(frozen=True)
class Family:
    """One family: its seed, shape model and scale, base material and class difference
    (`delta`: additive per field, except `shininess` and `relief_mm` whose entries are log
    factors), and the cues that difference is made of."""
    seed: int
    kind: str
    scale: float
    base: Material
    delta: dict
    cues: tuple


def _rng(*key) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([FAMILY_STREAM] + [int(k) for k in key]))


def _balanced(d: np.ndarray) -> np.ndarray:
    """An albedo difference whose power-weighted mean is 0 (all LEDs on see no change)."""
    return d - float(np.dot(d, CHANNEL_POWER) / CHANNEL_POWER.sum())


def draw_family(seed: int) -> Family:
    """The family of a seed (module docstring)."""
    rng = _rng(seed, 0)
    kind = str(rng.choice(synth.ALL_OBJECT_TYPES))
    flat = kind in FLAT_TYPES
    base = Material(
        albedo=tuple(rng.uniform(*ALBEDO_RANGE, 4)),
        pigment_contrast=tuple(rng.uniform(0, 0.2, 4)),
        pigment_scale_mm=float(rng.uniform(1.5, 5.0)),
        specular=float(rng.uniform(0.01, 0.08)),
        shininess=float(math.exp(rng.uniform(math.log(8), math.log(120)))),
        sss=tuple(rng.uniform(0, 0.6, 4)),
        sss_radius_mm=tuple(rng.uniform(0.5, 4.0, 4)),
        relief_mm=float(rng.uniform(0.01, 0.15)),
        relief_scale_mm=float(rng.uniform(1.0, 4.0)),
        emboss_mm=float(rng.uniform(0, 0.2)) if flat else 0.0,
        ink_contrast=tuple(rng.uniform(0, 0.5, 4)) if flat else (0.0,) * 4)
    allowed = [c for c in CUES if flat or c not in FLAT_ONLY_CUES]
    cues = tuple(str(c) for c in rng.choice(allowed, int(rng.integers(1, MAX_CUES + 1)),
                                            replace=False))
    delta = {name: np.zeros(4) if isinstance(getattr(base, name), tuple) else 0.0
             for name in Material.__dataclass_fields__}

    def size(cue, n=None):
        magnitude = CUE_SCALE[cue] * rng.uniform(0.5, 1.0, n)
        return magnitude * rng.choice([-1.0, 1.0], n)

    for cue in cues:
        if cue == "albedo":
            delta["albedo"] = delta["albedo"] + _balanced(size(cue, 4))
        elif cue == "nir":
            delta["albedo"] = delta["albedo"] + _balanced(np.array([0, 0, 0, size(cue)]))
        elif cue == "gloss":
            delta["specular"] += size(cue)
            delta["shininess"] += float(rng.uniform(-1.0, 1.0))
        elif cue == "relief":
            delta["relief_mm"] += size(cue)
        elif cue == "sss":
            delta["sss"] = delta["sss"] + size(cue, 4)
        elif cue == "pigment":
            delta["pigment_contrast"] = delta["pigment_contrast"] + size(cue, 4)
        elif cue == "ink":
            delta["ink_contrast"] = delta["ink_contrast"] + size(cue, 4)
        elif cue == "emboss":
            delta["emboss_mm"] += size(cue)
    delta = {k: tuple(float(x) for x in v) if isinstance(v, np.ndarray) else float(v)
             for k, v in delta.items()}
    return Family(int(seed), kind, float(rng.uniform(*SCALE_RANGE)), base, delta, cues)


def _clip(name: str, value: float) -> float:
    if name in FRACTION_FIELDS:
        return float(min(max(value, 0.0), 1.0))
    return float(max(value, 0.0))


def _shifted(material: Material, delta: dict, t: float) -> Material:
    """`material` moved by t x `delta` (log factors for shininess and relief depth)."""
    out = {}
    for name in Material.__dataclass_fields__:
        value, d = getattr(material, name), delta[name]
        if name in ("shininess", "relief_mm"):
            out[name] = _clip(name, value * math.exp(t * d))
        elif isinstance(value, tuple):
            out[name] = tuple(_clip(name, v + t * x) for v, x in zip(value, d))
        else:
            out[name] = _clip(name, value + t * d)
    return Material(**out)


def check_strength(strength: float) -> None:
    if not (math.isfinite(strength) and 0 <= strength <= MAX_STRENGTH):
        raise ValueError(f"strength must be 0 .. {MAX_STRENGTH:g} (0 = the two classes are "
                         f"one material), got {strength}")


def class_materials(family: Family, strength: float) -> tuple[Material, Material]:
    """The materials of classes a and b: the base -/+ strength / 2 x the difference."""
    check_strength(strength)
    return (_shifted(family.base, family.delta, -strength / 2),
            _shifted(family.base, family.delta, strength / 2))


def sample_draw(family: Family, class_index: int, sample: int, material: Material,
                sample_spread: float = DEFAULT_SAMPLE_SPREAD) -> dict:
    """One physical sample: its shape instance, jittered material, tint and gain. The draw
    depends on (family seed, class index, sample) only as a seed: every class draws from
    the same distribution."""
    rng = _rng(family.seed, 1, class_index, sample)
    shape = (flat_objects.instance_params(family.kind, rng) if family.kind in FLAT_TYPES
             else synth.instance_shape(family.kind, rng))
    shape["scale"] = shape["scale"] * family.scale
    overall = rng.uniform(0.9, 1.1)
    shape["tint"] = tuple(overall * rng.uniform(0.95, 1.05, 4))
    s = float(sample_spread)
    jitter = {
        "albedo": tuple(_clip("albedo", a * (1 + s * u))
                        for a, u in zip(material.albedo, rng.uniform(-1, 1, 4))),
        "relief_mm": material.relief_mm * math.exp(2 * s * rng.standard_normal()),
        "specular": _clip("specular", material.specular * math.exp(2 * s * rng.standard_normal())),
        "pigment_contrast": tuple(_clip("pigment_contrast", p * math.exp(2 * s * g)) for p, g in
                                  zip(material.pigment_contrast, rng.standard_normal(4))),
        "sss": tuple(_clip("sss", v + s * u) for v, u in zip(material.sss, rng.uniform(-1, 1, 4))),
    }
    return {"shape": shape, "material": replace(material, **jitter),
            "gain": float(1 + GAIN_SPREAD * rng.uniform(-1, 1))}


def render_family_pose(family: Family, class_index: int, sample: int, pose: int,
                       strength: float, rig, model_noise: float = 0.1,
                       sample_spread: float = DEFAULT_SAMPLE_SPREAD) -> np.ndarray:
    """The 32 single-LED images ``(4, sites, H, W)`` of one pose of one sample."""
    material = class_materials(family, strength)[class_index]
    drawn = sample_draw(family, class_index, sample, material, sample_spread)
    pose_params = synth._pose_params((FAMILY_STREAM, family.seed, 2, class_index, sample, pose),
                                     "free")
    shape = {**drawn["shape"], "scale": drawn["shape"]["scale"] * pose_params["scale"]}
    rng = _rng(family.seed, 3, class_index, sample, pose)
    images = synth.render_pose(family.kind, drawn["material"], shape, pose_params, rig, rng,
                               model_noise)
    return np.clip(images * drawn["gain"], 0, rig.max_level, out=images)


def describe(family: Family, strength: float, sample_spread: float) -> dict:
    """JSON-ready description (written as family.json next to the capture)."""
    a, b = class_materials(family, strength)
    return {"seed": family.seed, "kind": family.kind, "scale": family.scale,
            "cues": list(family.cues), "strength": strength, "sample_spread": sample_spread,
            "base": asdict(family.base), "delta": family.delta,
            "materials": {CLASS_NAMES[0]: asdict(a), CLASS_NAMES[1]: asdict(b)}}


def _write(out_dir: Path, family: Family, c: int, sample: int, pose: int, strength: float, rig,
           model_noise: float, sample_spread: float, compress_level: int) -> None:
    images = render_family_pose(family, c, sample, pose, strength, rig, model_noise,
                                sample_spread)
    write_pose(out_dir / CLASS_NAMES[c] / f"s{sample}" / f"p{pose:02d}", images, rig.bit_depth,
               compress_level)


def generate_family(out_dir, family_seed: int, strength: float = 1.0,
                    n_samples_per_class: int = 4, n_poses: int = 4, image_size: int = 64,
                    sample_spread: float = DEFAULT_SAMPLE_SPREAD, model_noise: float = 0.1,
                    n_jobs: int = 1, compress_level: int = 2, overwrite: bool = False,
                    progress=None) -> Path:
    """Write one family (module docstring) as a capture folder; returns its path.

    `family_seed` draws the family; `strength` scales the difference between the classes'
    materials (0 = one material: the chance-level control; 1 = the cue sizes of
    `CUE_SCALE`); `n_samples_per_class` physical samples per class, each in `n_poses` free
    placements; `sample_spread` scales how much samples of one class differ in material;
    `model_noise` is the residual noise (std, gray levels) of the averaged model captures.
    Deterministic for its arguments, whatever `n_jobs`. A non-empty `out_dir` is refused
    unless `overwrite`.
    """
    from joblib import Parallel, delayed

    check_strength(strength)
    if image_size < 16:
        raise ValueError(f"image_size must be >= 16 pixels, got {image_size}")
    if n_samples_per_class < 1 or n_poses < 1:
        raise ValueError("need at least one sample and one pose per class")
    if not (math.isfinite(sample_spread) and 0 <= sample_spread <= 0.5):
        raise ValueError(f"sample_spread must be 0 .. 0.5, got {sample_spread}")
    synth.check_render_memory(image_size, n_jobs if n_jobs > 0 else 1)
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()) and not overwrite:
        raise ValueError(f"{out_dir} is not empty; choose a new folder or pass overwrite "
                         "(--force)")
    out_dir.mkdir(parents=True, exist_ok=True)
    family = draw_family(family_seed)
    rig = synth.capture_rig(image_size)
    rig.save_yaml(out_dir / "rig.yaml")
    (out_dir / "family.json").write_text(json.dumps(describe(family, strength, sample_spread),
                                                    indent=1))
    jobs = [(c, s, p) for c in range(len(CLASS_NAMES)) for s in range(n_samples_per_class)
            for p in range(n_poses)]
    runner = Parallel(n_jobs=n_jobs, return_as="generator", batch_size=4)
    tasks = (delayed(_write)(out_dir, family, c, s, p, strength, rig, model_noise,
                             sample_spread, compress_level) for c, s, p in jobs)
    for done, _ in enumerate(runner(tasks), start=1):
        if progress is not None:
            progress(done, len(jobs))
    return out_dir


__all__ = ["CLASS_NAMES", "CUES", "Family", "class_materials", "describe", "draw_family",
           "generate_family", "render_family_pose", "sample_draw"]
