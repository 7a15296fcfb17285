"""Model capture and noise calibration through the graph on the simulated stage: time and error.

Brings up driver (Python firmware simulator), sim camera (dimmer 1.0, noise auto) and the
acquisition node as processes in a domain id of its own (LOCALHOST discovery), then

* captures one synthetic sample's model at N frames per LED image (default 1, 4, 16) at the
  paper's 15 dB / 30 ms, and reports the wall time per model, the exposure time it contains,
  and the RMS error of the captured model against the stored one (pixels no frame clips)
  next to what N frames predict;
* calibrates the camera noise on a calibration target at 15 dB / 30 ms with F frames per
  level (default 15, 30, 60, 120; 8 levels) and reports the fit, its standard errors and
  the error against the camera's configured noise (the paper's 0.7 / 66, plus 1/12 of
  rounding to whole gray levels).

    .venv/bin/python benchmarks/bench_acquisition.py [--size 240] [--frames 1 4 16]
        [--calibration-frames 15 30 60 120] [--exposure-us 30000] [--json OUT.json]
    .venv/bin/python benchmarks/bench_acquisition.py --quick   # 60 px, N 1 2, F 4 x 4 levels

Without ROS (`--core`): the calibration cases FRAMESxLEVELS (default the cases
120x8 30x8 30x6) through `calibration.calibrate_noise` on the simulated camera's frames (the
acquisition node's core, the same frames the graph delivers), `--seeds` repeats each, and the
mean error in stated standard errors. `--cause` adds the experiment behind the fit's pixel selection:
the same frames fitted with main's pixel-dropping rule and its variants.

    .venv/bin/python benchmarks/bench_acquisition.py --core [--cases 120x8 30x8 30x6]
        [--seeds 5] [--camera-dimmer 0.45] [--target-size 180 240] [--cause]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from lightstage_graph.graph_client import GraphClient
from lightstage_graph.limits import gain_db_fields

from _common import fresh_domain_id, parse_args, start_nodes, write_params


class StageGraph(GraphClient):
    """The benchmark's own ROS participant: starts nodes, sends action goals, sets
    parameters atomically."""

    def start(self, supervisor, names, params=None, timeout_s: float = 30.0) -> None:
        start_nodes(supervisor, self, names, self.domain_id, params, timeout_s)

    def action(self, action_type, name: str, goal, timeout_s: float = 120.0):
        """Send a goal; returns (status, result)."""
        handle = self.send_goal(action_type, name, goal, wait_s=15.0, timeout_s=15.0)
        if not handle.accepted:
            return None, None
        result = self.result(handle.get_result_async(), timeout_s, f'the result of {name}')
        return result.status, result.result

    def set_parameters(self, node_name: str, **values):
        """SetParametersAtomically on a node; returns the one SetParametersResult."""
        return self.set_parameters_atomically(node_name, values)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--size', type=int, default=240, help='synthetic sample image size (px)')
    p.add_argument('--frames', type=int, nargs='*', default=[1, 4, 16])
    p.add_argument('--calibration-frames', type=int, nargs='*', default=[15, 30, 60, 120])
    p.add_argument('--levels', type=int, default=8)
    p.add_argument('--target-size', type=int, nargs=2, default=[48, 64], metavar=('H', 'W'))
    p.add_argument('--exposure-us', type=int, default=30000)
    p.add_argument('--gain-db', type=float, default=15.0)
    p.add_argument('--domain-id', type=int, default=None)
    p.add_argument('--json', default='', help='also write the figures here')
    p.add_argument('--core', action='store_true', help='calibration cases without ROS')
    p.add_argument('--cases', nargs='*', default=['120x8', '30x8', '30x6'],
                   help='--core: FRAMESxLEVELS')
    p.add_argument('--seeds', type=int, default=5, help='--core: repeats per case')
    p.add_argument('--camera-dimmer', type=float, default=1.0,
                   help='--core: the sim camera\'s dimmer (the target is written for 1.0)')
    p.add_argument('--cause', action='store_true', help='--core: also main\'s rule and variants')
    args = parse_args(p, argv, size=60, frames=[1, 2], calibration_frames=[4], levels=4,
                      cases=['8x4'], seeds=2)
    if args.core:
        return core_calibration(args)

    from lightstage_graph.ros_env import apply_ros_environment
    domain_id = args.domain_id if args.domain_id is not None else fresh_domain_id()
    apply_ros_environment(domain_id)

    from lightstage_bringup.supervisor import Supervisor
    from lightstage_physics import synth
    from lightstage_physics.calibration_target import write_calibration_target
    from lightstage_physics.capture_format import load_capture
    from lightstage_physics.noise import PAPER_CALIBRATION
    from lightstage_interfaces.action import CalibrateNoise, CaptureModel

    work = Path(tempfile.mkdtemp(prefix='bench-acquisition-'))
    fruit = synth.generate(work / 'fruit', image_size=args.size, n_samples_per_class=1,
                           n_poses=1, object_types=('banana',), n_jobs=1)
    target = write_calibration_target(work / 'target', shape=tuple(args.target_size), dimmer=1.0)
    sample = 'banana-real/s0/p00'
    params = write_params(work / 'params.yaml', {
        'camera': {'capture_dir': str(fruit), 'sample': sample, 'dimmer': 1.0, 'seed': 0},
        'acquisition': {'timeout_s': 30.0}})
    stored = load_capture(fruit, cache=False)
    truth = stored.models[stored.sample_names.index(sample)].astype(np.float64)
    noise = PAPER_CALIBRATION.at(args.gain_db, args.exposure_us / 1000)
    figures = {'size': args.size, 'exposure_us': args.exposure_us, 'gain_db': args.gain_db,
               'capture': [], 'calibration': []}
    frame_s = args.exposure_us / 1e6

    client = StageGraph(domain_id)
    with Supervisor(sigint_timeout_s=5.0, stdout=open(work / 'nodes.log', 'w'),
                    stderr=open(work / 'nodes.err', 'w')) as supervisor:
        client.start(supervisor, ['driver', 'camera', 'acquisition'], params)

        def run(action_type, name, goal, n_exposures):
            """The action's result (None if the goal was rejected); the time limit grows
            with the exposures the goal takes."""
            _, result = client.action(action_type, name, goal,
                                         timeout_s=120.0 + 5 * n_exposures * frame_s)
            return result

        clear = truth - 6 * np.sqrt(noise.variance(truth)) > 0
        for n in args.frames:
            out = work / f'capture_n{n}'
            start = time.perf_counter()
            r = run(CaptureModel, '/lightstage/capture_model', CaptureModel.Goal(
                output_dir=str(out), label='banana-real', sample='s0', pose='p00',
                exposure_us=args.exposure_us, frames_averaged=n, **gain_db_fields(args.gain_db)),
                n_exposures=32 * (n + 1))
            wall = time.perf_counter() - start
            if r is None or not r.success:
                print(f'capture N={n} failed: {r.message if r else "goal rejected"}',
                      file=sys.stderr)
                return 1
            model = load_capture(out, cache=False).models[0].astype(np.float64)
            rms = float(np.sqrt(np.mean((model[clear] - truth[clear]) ** 2)))
            predicted = float(np.sqrt(np.mean(noise.variance(truth[clear]) / n + 1 / 12 / n)))
            exposure_s = 32 * (n + 1) * args.exposure_us / 1e6  # + 1: the preview
            row = {'frames': n, 'wall_s': round(wall, 2), 'exposure_s': round(exposure_s, 2),
                   'overhead_ms_per_frame': round(1e3 * (wall - exposure_s) / (32 * (n + 1)), 1),
                   'rms_error': round(rms, 3), 'rms_predicted': round(predicted, 3),
                   'clear_pixels': int(clear.sum())}
            figures['capture'].append(row)
            print(f'capture N={n:3d}: {wall:6.1f} s per model ({exposure_s:.1f} s of exposure, '
                  f'{row["overhead_ms_per_frame"]} ms overhead per frame); RMS error vs the '
                  f'stored model {rms:.3f} gray levels (predicted {predicted:.3f}, '
                  f'{row["clear_pixels"]} unclipped pixels)', flush=True)

        result = client.set_parameters('camera', capture_dir=str(target), sample='0')
        assert result.successful, result.reason
        exact = PAPER_CALIBRATION.at(args.gain_db, args.exposure_us / 1000)
        for frames in args.calibration_frames:
            start = time.perf_counter()
            r = run(CalibrateNoise, '/lightstage/calibrate_noise', CalibrateNoise.Goal(
                exposure_us=args.exposure_us, frames_per_level=frames, **gain_db_fields(args.gain_db),
                levels=args.levels), n_exposures=frames * args.levels)
            wall = time.perf_counter() - start
            if r is None or not r.success:
                print(f'calibration F={frames} failed: {r.message if r else "goal rejected"}',
                      file=sys.stderr)
                return 1
            dp = r.sigma_p2 - exact.sigma_p2
            dr = r.sigma_r2 - (exact.sigma_r2 + 1 / 12)
            row = {'frames_per_level': frames, 'levels': args.levels, 'wall_s': round(wall, 1),
                   'sigma_p2': round(r.sigma_p2, 4), 'sigma_p2_stderr': round(r.sigma_p2_stderr, 4),
                   'sigma_r2': round(r.sigma_r2, 2), 'sigma_r2_stderr': round(r.sigma_r2_stderr, 2),
                   'error_sigma_p2_in_se': round(dp / r.sigma_p2_stderr, 2),
                   'error_sigma_r2_in_se': round(dr / r.sigma_r2_stderr, 2),
                   'pixels_used': int(r.pixels_used)}
            figures['calibration'].append(row)
            print(f'calibration F={frames:3d} x {args.levels} levels: {wall:5.1f} s; '
                  f'sigma_p2 {r.sigma_p2:.4f} +- {r.sigma_p2_stderr:.4f} '
                  f'(true {exact.sigma_p2:.4f}, {dp / r.sigma_p2_stderr:+.1f} se), '
                  f'sigma_r2 {r.sigma_r2:.2f} +- {r.sigma_r2_stderr:.2f} '
                  f'(true {exact.sigma_r2 + 1 / 12:.2f} with rounding, '
                  f'{dr / r.sigma_r2_stderr:+.1f} se), {r.pixels_used} pixels', flush=True)
    client.close()
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    print(f'(work files in {work})')
    return 0


def core_calibration(args) -> int:
    """The calibration cases through the pure core on sim camera frames (see the docstring)."""
    from lightstage_camera import calibration as cal
    from lightstage_physics.calibration_target import write_calibration_target
    from lightstage_physics.capture_format import load_capture
    from lightstage_graph.frames import mono16_to_gray
    from lightstage_physics.noise import PAPER_CALIBRATION
    from lightstage_camera.sim_camera import SimCamera

    work = Path(tempfile.mkdtemp(prefix='bench-calibration-'))
    target_dir = write_calibration_target(work / 'target', shape=tuple(args.target_size),
                                              dimmer=1.0)
    target = load_capture(target_dir, cache=False)
    truth = PAPER_CALIBRATION.at(args.gain_db, args.exposure_us / 1000)
    exact = np.array([truth.sigma_p2, truth.sigma_r2 + 1 / 12])  # + rounding
    print(f'{args.target_size[0]} x {args.target_size[1]} target, camera dimmer '
          f'{args.camera_dimmer:g}, {args.gain_db:g} dB / {args.exposure_us / 1000:g} ms, true '
          f'{exact[0]:.4f} / {exact[1]:.3f}; {args.seeds} seeds per case (mean fit, mean stated '
          'se, mean error in se, sd of the fits over seeds)')
    rows = []
    for case in args.cases:
        frames, levels = (int(v) for v in case.lower().split('x'))
        settings = cal.CalibrationSettings(exposure_us=args.exposure_us, gain_db=args.gain_db,
                                           frames_per_level=frames, levels=levels)
        fits, errors, variants = [], [], {}
        for seed in range(args.seeds):
            cam = SimCamera(target, dimmer=args.camera_dimmer, seed=seed)
            stacks = []

            def grab(patterns, stacks=stacks):
                shots = [cam.capture(patterns[:, j], args.exposure_us, args.gain_db)
                         for j in range(patterns.shape[1])]
                stacks.append(np.array([mono16_to_gray(f, cam.bit_depth) for f in shots]))
                return shots

            r = cal.calibrate_noise(grab, settings)
            fits.append((r.model.sigma_p2, r.model.sigma_r2))
            errors.append(r.stderr)
            if args.cause:
                for name, fit in _variants(_levels_frames(stacks, levels), truth).items():
                    variants.setdefault(name, []).append(fit)
        fits, errors = np.array(fits), np.array(errors)
        z = (fits.mean(0) - exact) / errors.mean(0)
        row = {'case': case, 'sigma_p2': round(float(fits[:, 0].mean()), 4),
               'sigma_r2': round(float(fits[:, 1].mean()), 3),
               'se': [round(float(v), 4) for v in errors.mean(0)],
               'error_in_se': [round(float(v), 2) for v in z],
               'sd_over_seeds': [round(float(v), 4) for v in fits.std(0, ddof=1)]
               if args.seeds > 1 else None}
        rows.append(row)
        print(f'{case:>6}: sigma_p2 {row["sigma_p2"]:.4f} (+-{row["se"][0]:.4f}, {z[0]:+.1f} se), '
              f'sigma_r2 {row["sigma_r2"]:.2f} (+-{row["se"][1]:.2f}, {z[1]:+.1f} se); '
              f'sd over seeds {row["sd_over_seeds"]}', flush=True)
        for name, got in variants.items():
            got = np.array(got)
            print(f'        {name:44s} sigma_p2 {got[:, 0].mean():.4f}, sigma_r2 '
                  f'{got[:, 1].mean():.2f}', flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def _levels_frames(stacks, levels):
    """The grabbed request stacks joined into one (frames, H, W) stack per level."""
    per = len(stacks) // levels
    return [np.concatenate(stacks[i * per:(i + 1) * per], 0) for i in range(levels)]


def _variants(levels_frames, truth):
    """sigma_p2, sigma_r2 of the same frames under main's rule and its variants: each pixel's
    (mean, variance) over all frames, binned by that mean into 60 quantile bins, a weighted
    least-squares line (weights from the true noise, so only the points differ)."""
    m = np.concatenate([s.mean(0).ravel() for s in levels_frames])
    out = {}
    for name, ddof, drop_by_own in (('main: drop by own sd, ddof 1', 1, True),
                                    ('main with ddof 0', 0, True),
                                    ('drop by the true model sd, ddof 1', 1, False)):
        v = np.concatenate([s.var(0, ddof=ddof).ravel() for s in levels_frames])
        sd = np.sqrt(v) if drop_by_own else np.sqrt(truth.variance(m) + 1 / 12)
        keep = (m - 4 * sd > 0) & (m + 4 * sd < truth.max_level)
        edges = np.quantile(m[keep], np.linspace(0, 1, 61))
        which = np.clip(np.searchsorted(edges, m[keep], side='right') - 1, 0, 59)
        count = np.bincount(which, minlength=60)
        bm = np.bincount(which, m[keep], 60) / count
        bv = np.bincount(which, v[keep], 60) / count
        slope, intercept = np.polyfit(bm, bv, 1, w=np.sqrt(count) / truth.variance(bm))
        out[name] = (slope, intercept)
    return out


if __name__ == '__main__':
    sys.exit(main())
