"""Synthetic light-stage data: relightable models of real and fake objects, planned and written.

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

The rendering of one pose is `fruit_render`'s, the materials are `materials`'; this module
plans the samples and poses of a dataset, seeds them, renders them in parallel and writes them.
`lightstage synth OUT_DIR` (`synth_cli`) writes the capture folder format (docs/CAPTURE_FORMAT.md).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from . import flat_objects
from .capture_format import write_pose
from .flat_objects import FLAT_TYPES
# the renderer's and the materials' names stay importable from here, where the dataset's are
from .fruit_render import (CHANNEL_POWER, DIFFUSER_SHININESS, FLOOR_ALBEDO,  # noqa: F401
                           OBJECT_TYPES, PENUMBRA_MM, WHITE_LEVEL_PER_LED, instance_shape,
                           render_pose)
from .materials import (FRACTION_FIELDS, MATERIALS, MAX_STRENGTH, Material,
                        blend_materials)
from .rig import Rig

# OBJECT_TYPES (fruit_render): the default set
ALL_OBJECT_TYPES = OBJECT_TYPES + FLAT_TYPES
PLACEMENTS = ("canonical", "free")
VARIANTS = ("fake", "real")
DEFAULT_SIZE = 240
DEFAULT_SAMPLES = 4
DEFAULT_POSES = 5
DEFAULT_SEED = 0


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
              else instance_shape(kind, rng))
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
