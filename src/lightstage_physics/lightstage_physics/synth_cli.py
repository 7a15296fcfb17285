"""`lightstage synth`: write the synthetic light-stage dataset, a procedural object family or a
noise-calibration target as a capture folder (the command line of `synth` and `families`)."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import flat_objects
from .families import DEFAULT_SAMPLE_SPREAD, draw_family, generate_family
from .rig import DEFAULT_DIMMER
from .synth import (ALL_OBJECT_TYPES, DEFAULT_POSES, DEFAULT_SAMPLES, DEFAULT_SEED, DEFAULT_SIZE,
                    FREE_SCALE, FREE_SHIFT_MM, OBJECT_TYPES, PLACEMENTS, generate)
from .workers import jobs_type


def _progress(quiet: bool):
    """A progress callback (done, total) that counts rendered poses on stderr."""
    def progress(done, total):
        if not quiet and (done == total or done % 10 == 0):
            print(f"\r{done}/{total} poses rendered", end="" if done < total else "\n",
                  file=sys.stderr, flush=True)
    return progress


def _dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*.png"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="lightstage synth",
        description="Write the synthetic light-stage dataset (relightable models of real "
                    "and fake objects) as a capture folder. Object types: the five fruit "
                    "(default) and flat objects whose classes differ only under particular "
                    "light: coin (embossed brass token vs a flat print of it: alike under "
                    "all LEDs, apart under grazing light), note (paper note whose inks are "
                    "NIR-transparent vs a copy whose inks absorb NIR) and seal (a card with a "
                    f"seal pressed {flat_objects.PRINTED_RELIEF_MM['seal']} mm into relief vs "
                    "a flat print of it). Each flat fake "
                    "is a copy of the real sample with the same number.")
    parser.add_argument("out_dir", help="folder to write (created if missing)")
    parser.add_argument("--size", type=int, default=DEFAULT_SIZE,
                        help=f"image side in pixels (default {DEFAULT_SIZE})")
    parser.add_argument("--poses", type=int, default=DEFAULT_POSES,
                        help=f"poses per sample (default {DEFAULT_POSES})")
    parser.add_argument("--samples", type=int, default=DEFAULT_SAMPLES,
                        help=f"samples (instances) per class (default {DEFAULT_SAMPLES})")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--types", default=",".join(OBJECT_TYPES),
                        help="comma-separated object types, from "
                             f"{', '.join(ALL_OBJECT_TYPES)} (default: the five fruit)")
    parser.add_argument("--placement", choices=PLACEMENTS, default="canonical",
                        help="how objects lie on the stage: canonical (roughly the same way "
                             "up: +-35 deg, +-8 mm off centre; the default) or free (any "
                             f"in-plane rotation, +-{FREE_SHIFT_MM:g} mm off centre, scale "
                             f"{FREE_SCALE[0]:g}..{FREE_SCALE[1]:g})")
    parser.add_argument("--strength", type=float, default=1.0,
                        help="scale of the real/fake differences (default 1)")
    parser.add_argument("--jobs", type=jobs_type, default=2, help="parallel processes (default 2)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder (same-named files are replaced)")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--calibration-target", action="store_true",
                        help="write a noise-calibration target instead (one sample, "
                             "calibration-target/s0/p00, a reflectance ramp; for `lightstage "
                             "calibrate` on the simulated stage; --size is its width, 3/4 of it "
                             "its height)")
    parser.add_argument("--family", type=int, metavar="SEED",
                        help="write one procedural object family instead "
                             "(lightstage_physics.families): the seed draws a shape and two "
                             "class materials (family-a, family-b) that differ in 1-3 optical "
                             "properties, the difference scaled by --strength (0 = one material, "
                             "the chance-level control); --samples physical samples per class, "
                             "each with its own size, shape, material jitter, tint and gain, in "
                             "--poses free placements (--types and --placement do not apply)")
    parser.add_argument("--sample-spread", type=float, default=None,
                        help="with --family: how much samples of one class differ in material "
                             "(default 0.05: albedo per colour +-5 %%, relief, gloss and mottle "
                             "x exp(N(0, 0.1)))")
    parser.add_argument("--dimmer", type=float, default=DEFAULT_DIMMER,
                        help="with --calibration-target: the sim camera's dimmer, so that all "
                             "LEDs bring the target's brightest pixel to 1.1 x the camera's "
                             f"maximum (default {DEFAULT_DIMMER:g}, the camera node's default)")
    args = parser.parse_args(argv)
    if args.calibration_target:
        from .calibration_target import CALIBRATION_TARGET_NAME, write_calibration_target
        try:
            out = write_calibration_target(args.out_dir, (max(4, args.size * 3 // 4), args.size),
                                           dimmer=args.dimmer, overwrite=args.force)
        except ValueError as exc:
            print(f"lightstage synth: {exc}", file=sys.stderr)
            return 2
        if not args.quiet:
            print(f"wrote {out} (calibration target {CALIBRATION_TARGET_NAME}, "
                  f"{args.size}x{max(4, args.size * 3 // 4)} px)")
        return 0
    if args.family is not None:
        return _family_main(args)
    if args.sample_spread is not None:
        parser.error("--sample-spread needs --family")
    types = [t.strip() for t in args.types.split(",") if t.strip()]
    unknown = [t for t in types if t not in ALL_OBJECT_TYPES]
    if unknown:
        parser.error(f"unknown object type(s) {unknown}; choose from "
                     f"{', '.join(ALL_OBJECT_TYPES)}")
    start = time.perf_counter()
    progress = _progress(args.quiet)

    try:
        out = generate(args.out_dir, args.size, args.samples, args.poses, args.seed, types,
                       n_jobs=args.jobs, strength=args.strength, progress=progress,
                       overwrite=args.force, placement=args.placement)
    except ValueError as exc:
        print(f"lightstage synth: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(f"wrote {out} ({len(types) * 2} classes x {args.samples} samples x {args.poses} "
              f"poses, {args.placement} placement, {_dir_size(out) / 1e6:.0f} MB) in "
              f"{time.perf_counter() - start:.1f} s")
    return 0


def _family_main(args) -> int:
    """`lightstage synth OUT --family SEED`: one procedural family as a capture folder."""
    spread = DEFAULT_SAMPLE_SPREAD if args.sample_spread is None else args.sample_spread
    start = time.perf_counter()
    progress = _progress(args.quiet)

    try:
        out = generate_family(args.out_dir, args.family, args.strength, args.samples,
                              args.poses, args.size, sample_spread=spread, n_jobs=args.jobs,
                              overwrite=args.force, progress=progress)
    except ValueError as exc:
        print(f"lightstage synth: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        family = draw_family(args.family)
        print(f"wrote {out} (family {args.family}: {family.kind} shape, cues "
              f"{', '.join(family.cues)}, strength {args.strength:g}; 2 classes x "
              f"{args.samples} samples x {args.poses} poses, free placement, "
              f"{_dir_size(out) / 1e6:.1f} MB) in {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
