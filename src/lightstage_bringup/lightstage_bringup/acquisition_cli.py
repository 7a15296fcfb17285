"""`lightstage capture` and `lightstage calibrate`: clients of the acquisition node's actions.

``capture`` sends one CaptureModel goal per target pose (``/lightstage/capture_model``) and
prints the progress; ``calibrate`` sends a CalibrateNoise goal (``/lightstage/calibrate_noise``)
and prints the fitted noise model and its generalization to the Sigma1..3 settings. On the
simulated stage the camera node's parameters (which sample is on the stage, which capture
folder it renders from) can be set first: ``TARGET=SIM_SAMPLE``, ``--camera-param``.

Exit codes: 0 done; 1 the node refused or failed a goal (its message is printed), or went
away while the goal ran (killed: the CLI says so a few seconds later, not never); 2 bad
arguments; 3 the action server (or the camera node, for camera parameters) is not available;
130 interrupted (the running goal is cancelled first and how it ended is printed: a
cancelled goal leaves nothing half-written). ``capture DIR --from-rescued FILE`` writes a
pose whose capture could not be written (the error named FILE) without ROS.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from pathlib import Path

from lightstage_graph.names import CALIBRATE_ACTION, CAPTURE_ACTION
from lightstage_graph.ros_env import apply_ros_environment

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNAVAILABLE, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
TEARDOWN_S = 10.0  # destroying the ROS client after the outcome is printed
TARGET = re.compile(r'^([^/=]+)/([^/=]+)/([^/=]+)(?:=(.+))?$')


class _Failed(Exception):
    """The node refused or failed; the message says why."""
    exit_code = EXIT_FAILED


class _Unavailable(_Failed):
    """The action server (or the camera node) is not there."""
    exit_code = EXIT_UNAVAILABLE


# --------------------------------------------------------------------------- arguments


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument('--exposure-us', type=int, default=0,
                   help='exposure per frame [us] (default 0: the node\'s setting)')
    p.add_argument('--gain-db', type=float, default=math.nan,
                   help='camera gain [dB] (default: the node\'s setting)')
    p.add_argument('--overwrite', action='store_true',
                   help='replace what exists (a pose / the output files) instead of refusing')
    p.add_argument('--camera-param', action='append', default=[], metavar='NAME=VALUE',
                   help='set a parameter of the camera node first (simulated stage), e.g. '
                        'capture_dir=/data/synth or dimmer=1.0; repeatable')
    p.add_argument('--camera-node', default='camera',
                   help='name of the camera node for camera parameters (default camera)')
    p.add_argument('--wait-s', type=float, default=10.0,
                   help='how long to wait for the acquisition node (and camera node) [s]')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID of the graph (default: $ROS_DOMAIN_ID or 0)')
    p.add_argument('--json', action='store_true', help='print the results as JSON on stdout')
    p.add_argument('--quiet', action='store_true', help='no progress lines')


def _capture_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='lightstage capture',
        description='Capture relightable models of the sample on the stage into a capture '
                    'folder (docs/CAPTURE_FORMAT.md): one image per single LED, frames '
                    'averaged, through the acquisition node (`lightstage up driver camera '
                    'acquisition`).',
        epilog='TARGET is label/sample/pose, e.g. banana-fake/s0/p00; one goal per target, in '
               'order. On the simulated stage, TARGET=SIM_SAMPLE first puts SIM_SAMPLE (a name '
               'or index in the camera\'s capture folder) on the stage. With several targets '
               'and a terminal, you are asked to place each one (--no-prompt to skip). '
               'Exit codes: 0 all captured, 1 a capture failed (later targets are not '
               'attempted), 2 bad arguments, 3 node not available, 130 interrupted.')
    p.add_argument('output_dir', help='capture folder to write into (created if missing)')
    p.add_argument('targets', nargs='*', metavar='TARGET', help='label/sample/pose[=SIM_SAMPLE]')
    p.add_argument('--from-rescued', default='', metavar='FILE',
                   help='no capture: write the pose kept in FILE (named by a capture that could '
                        'not write it) into output_dir, then delete FILE')
    p.add_argument('--frames', type=int, default=0,
                   help='frames averaged per LED image (default 0: the node\'s frames_averaged)')
    p.add_argument('--prompt', dest='prompt', action='store_true', default=None,
                   help='ask before each target (default: with several targets on a terminal)')
    p.add_argument('--no-prompt', dest='prompt', action='store_false')
    _common(p)
    return p


def _calibrate_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='lightstage calibrate',
        description='Characterize the camera noise on the stage: a calibration target (a flat '
                    'chart of smoothly varying reflectance) lit at increasing levels, many '
                    'frames each, line fit variance = sigma_p2 * mean + sigma_r2; writes a '
                    'noise file the sim camera (noise_file) can use, and optionally the plot.',
        epilog='On the simulated stage: `lightstage synth DIR --calibration-target`, then '
               '--camera-param capture_dir=DIR --camera-param sample=0. Exit codes: 0 done, '
               '1 the calibration failed, 2 bad arguments, 3 node not available, '
               '130 interrupted.')
    p.add_argument('output', nargs='?', default='',
                   help='noise file (YAML) to write; omit to only print the fit')
    p.add_argument('--plot', default='', metavar='PNG', help='also draw the noise characteristic')
    p.add_argument('--frames', type=int, default=0,
                   help='frames per illumination level (default 0: the node\'s; the paper: 120)')
    p.add_argument('--levels', type=int, default=0,
                   help='illumination levels (default 0: the node\'s, 8)')
    _common(p)
    return p


def parse_target(text: str) -> tuple[str, str, str, str]:
    """'label/sample/pose[=SIM_SAMPLE]' -> (label, sample, pose, sim_sample or '')."""
    m = TARGET.match(text.strip())
    if not m:
        raise ValueError(f'target {text!r}: expected label/sample/pose (e.g. banana-fake/s0/p00), '
                         'optionally =SIM_SAMPLE')
    return m.group(1), m.group(2), m.group(3), m.group(4) or ''


def parse_param(text: str):
    """'name=value' -> (name, bool | int | float | str)."""
    name, sep, raw = text.partition('=')
    if not sep or not name.strip():
        raise ValueError(f'--camera-param {text!r}: expected NAME=VALUE, e.g. sample=3')
    raw = raw.strip()
    if raw.lower() in ('true', 'false'):
        return name.strip(), raw.lower() == 'true'
    for kind in (int, float):
        try:
            return name.strip(), kind(raw)
        except ValueError:
            pass
    return name.strip(), raw


def _absolute(path: str) -> str:
    """Paths go to the node, which may run in another directory: make them absolute."""
    return str(Path(path).expanduser().absolute()) if path.strip() else ''


# --------------------------------------------------------------------------- ROS


START_HINT = 'start the graph with `lightstage up driver camera acquisition` in this domain'


def _set_camera_params(graph, camera_node: str, params: list, wait_s: float) -> None:
    """Set camera parameters together (SetParametersAtomically: the camera sees e.g. a new
    capture_dir and the sample in it as one change)."""
    from lightstage_graph.graph_client import GraphTimeout
    if not params:
        return
    try:
        result = graph.set_parameters_atomically(
            camera_node, dict(params), wait_s=wait_s,
            hint='start the camera (`lightstage up driver camera acquisition`) or check --camera-node')
    except GraphTimeout as exc:
        raise _Unavailable(str(exc)) from None
    if not result.successful:
        shown = ', '.join(f'{n}={v!r}' for n, v in params)
        raise _Failed(f'the camera refused {shown}: {result.reason}')


def _run_goal(graph, action_type, name: str, goal, wait_s: float, on_feedback):
    """Send `goal`, spin until its result; Ctrl-C cancels it and re-raises. A server that
    goes away meanwhile (the acquisition node killed) fails the goal with the reason."""
    from action_msgs.msg import GoalStatus
    from lightstage_graph.graph_client import GraphTimeout, ServerLost
    try:
        handle = graph.send_goal(action_type, name, goal, wait_s, on_feedback, hint=START_HINT)
    except GraphTimeout as exc:
        raise _Unavailable(str(exc)) from None
    if not handle.accepted:
        raise _Failed(f'{name} refused the goal: another capture or calibration is running on '
                      'the stage (one goal at a time); try again when it is done')
    result_future = handle.get_result_async()
    try:
        answer = graph.goal_result(handle, result_future, name)
    except ServerLost as exc:
        raise _Failed(str(exc)) from None
    except KeyboardInterrupt:
        print('\ninterrupted: cancelling the goal ...', file=sys.stderr)
        handle.cancel_goal_async()
        try:
            answer = graph.result(result_future, 30.0, 'the cancel')
        except GraphTimeout:
            print(f'{name} did not confirm the cancel within 30 s: check the acquisition '
                  'node\'s log for what it wrote', file=sys.stderr)
        else:
            # the goal may have ended before the cancel reached it (e.g. already written)
            print(f'the goal ended {_status_name(answer.status)}: {answer.result.message}',
                  file=sys.stderr)
        raise
    return answer.status == GoalStatus.STATUS_SUCCEEDED, answer.result, answer.status


def _status_name(status: int) -> str:
    from action_msgs.msg import GoalStatus
    return {GoalStatus.STATUS_SUCCEEDED: 'succeeded', GoalStatus.STATUS_ABORTED: 'aborted',
            GoalStatus.STATUS_CANCELED: 'canceled'}.get(status, f'status {status}')


def _setup(args):
    """Validate the shared options and enter the ROS environment; returns camera params."""
    if args.exposure_us < 0 or args.frames < 0 or args.wait_s < 0:
        raise ValueError('--exposure-us, --frames and --wait-s must be >= 0')
    params = [parse_param(p) for p in args.camera_param]
    apply_ros_environment(args.domain_id)  # before rclpy is imported: LOCALHOST discovery
    return params


def _run(args, verb: str, params: list, work, report=None) -> int:
    """On a client of its own: set the camera parameters, then `work(graph)` -> exit code.
    The node refusing, failing or missing, and Ctrl-C (or the end of input at a prompt),
    end it with their exit code, the message printed. `report()` prints the outcome, before
    the client is torn down (within TEARDOWN_S, or the process ends with the exit code)."""
    from lightstage_graph.deadline import ExitDeadline
    from lightstage_graph.graph_client import GraphClient
    graph = GraphClient(args.domain_id, f'lightstage_acquisition_cli_{os.getpid()}')
    code = EXIT_FAILED
    try:
        _set_camera_params(graph, args.camera_node, params, args.wait_s)
        code = work(graph)
    except _Failed as exc:
        print(f'lightstage {verb}: {exc}', file=sys.stderr, flush=True)
        code = exc.exit_code
    except (KeyboardInterrupt, EOFError):
        code = EXIT_INTERRUPTED
    finally:
        if report is not None:
            report()
        sys.stdout.flush()
        # destroying the participant is the one wait no timeout reaches (classify_cli)
        with ExitDeadline(TEARDOWN_S, f'lightstage {verb}', code,
                          phase='shutting down its ROS client (its outcome above is complete)'):
            graph.close()
    return code


def _progress(args, text: str, end: bool = False) -> None:
    """A progress line, rewritten in place on a terminal; elsewhere only the final lines."""
    if args.quiet:
        return
    if sys.stderr.isatty():
        print(f'\r{text}\033[K', end='\n' if end else '', file=sys.stderr, flush=True)
    elif end:
        print(text, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- capture


def capture_main(argv: list[str] | None = None) -> int:
    args = _capture_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.from_rescued:
        return _write_rescued(args)
    try:
        if not args.targets:
            raise ValueError('give at least one TARGET (label/sample/pose), or --from-rescued FILE')
        targets = [parse_target(t) for t in args.targets]
        params = _setup(args)
    except ValueError as exc:
        print(f'lightstage capture: {exc}', file=sys.stderr)
        return EXIT_USAGE
    prompt = args.prompt if args.prompt is not None else (len(targets) > 1 and sys.stdin.isatty())
    from lightstage_interfaces.action import CaptureModel
    results = []

    def capture_targets(graph) -> int:
        for label, sample, pose, sim_sample in targets:
            name = f'{label}/{sample}/{pose}'
            if sim_sample:
                _set_camera_params(graph, args.camera_node, [('sample', sim_sample)], args.wait_s)
            elif prompt:
                input(f'place {label} {sample} in pose {pose} on the stage, then press Enter '
                      '(Ctrl-C stops) ')
            goal = CaptureModel.Goal(output_dir=_absolute(args.output_dir), label=label,
                                     sample=sample, pose=pose, exposure_us=args.exposure_us,
                                     gain_db=args.gain_db, frames_averaged=args.frames,
                                     overwrite=args.overwrite)
            start = time.monotonic()

            def feedback(f, name=name):
                what = f'{f.images_done}/{f.images_total} {f.current_led}' if f.stage == 'capturing' \
                    else f.stage
                _progress(args, f'{name}: {what}')

            ok, r, status = _run_goal(graph, CaptureModel, CAPTURE_ACTION, goal, args.wait_s, feedback)
            entry = {'target': name, 'success': ok, 'status': _status_name(status),
                     'message': r.message, 'model_dir': r.model_dir,
                     'images_captured': int(r.images_captured),
                     'saturated_pixels': int(r.saturated_pixels), 'elapsed_s': float(r.elapsed_s),
                     'wall_s': time.monotonic() - start}
            results.append(entry)
            _progress(args, f'{name}: {r.message}' if ok else f'{name}: {_status_name(status)}: '
                      f'{r.message}', end=True)
            if not ok:
                return EXIT_FAILED
        return EXIT_OK

    def report():
        if args.json:
            print(json.dumps(results), flush=True)

    return _run(args, 'capture', params, capture_targets, report)


def _write_rescued(args) -> int:
    from lightstage_physics.errors import DestinationError
    from lightstage_camera.rescue import write_rescued
    if args.targets:
        print('lightstage capture: --from-rescued writes the pose named in the file; give no '
              'TARGET', file=sys.stderr)
        return EXIT_USAGE
    try:
        pose_dir = write_rescued(args.from_rescued, args.output_dir, overwrite=args.overwrite)
    except DestinationError as exc:
        print(f'lightstage capture: {exc}', file=sys.stderr)
        return EXIT_FAILED
    if args.json:
        print(json.dumps([{'target': '/'.join(pose_dir.parts[-3:]), 'success': True,
                           'model_dir': str(pose_dir), 'rescued_from': args.from_rescued}]))
    else:
        print(f'wrote {pose_dir} from {args.from_rescued} (removed)')
    return EXIT_OK


# --------------------------------------------------------------------------- calibrate


def format_calibration(r) -> str:
    """The fit, its standard errors and the generalization to Sigma1..3."""
    from lightstage_physics.noise import SETTINGS, NoiseModel
    model = NoiseModel(r['sigma_p2'], r['sigma_r2'], gain_db=r['gain_db'],
                       exposure_ms=r['exposure_ms'])
    lines = [f'variance = {r["sigma_p2"]:.4f} (+-{r["sigma_p2_stderr"]:.4f}) * mean + '
             f'{r["sigma_r2"]:.2f} (+-{r["sigma_r2_stderr"]:.2f})  at {r["gain_db"]:g} dB, '
             f'{r["exposure_ms"]:g} ms  ({r["pixels_used"]} pixels)']
    for name, (g, e) in SETTINGS.items():
        m = model.at(g, e)
        lines.append(f'  {name}: {g:g} dB, {e:g} ms -> {m.sigma_p2:.3f} * mean + {m.sigma_r2:.2f}')
    for key, what in (('output_path', 'noise file'), ('plot_path', 'plot')):
        if r[key]:
            lines.append(f'{what}: {r[key]}')
    return '\n'.join(lines)


def calibrate_main(argv: list[str] | None = None) -> int:
    args = _calibrate_parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if args.levels < 0:
            raise ValueError('--levels must be >= 0')
        params = _setup(args)
    except ValueError as exc:
        print(f'lightstage calibrate: {exc}', file=sys.stderr)
        return EXIT_USAGE
    from lightstage_interfaces.action import CalibrateNoise
    goal = CalibrateNoise.Goal(output_path=_absolute(args.output), plot_path=_absolute(args.plot),
                               exposure_us=args.exposure_us, gain_db=args.gain_db,
                               frames_per_level=args.frames, levels=args.levels,
                               overwrite=args.overwrite)
    answers = []

    def calibrate(graph) -> int:
        def feedback(f):
            _progress(args, f'level {f.level}/{f.levels} ({f.leds_lit} LEDs): '
                      f'{f.frames_done}/{f.frames_total} frames' if f.stage == 'capturing'
                      else f.stage)

        ok, r, status = _run_goal(graph, CalibrateNoise, CALIBRATE_ACTION, goal, args.wait_s,
                                  feedback)
        answers.append({'success': ok, 'status': _status_name(status), 'message': r.message,
                        'output_path': r.output_path, 'plot_path': r.plot_path,
                        'sigma_p2': r.sigma_p2, 'sigma_r2': r.sigma_r2,
                        'sigma_p2_stderr': r.sigma_p2_stderr, 'sigma_r2_stderr': r.sigma_r2_stderr,
                        'gain_db': r.gain_db, 'exposure_ms': r.exposure_ms,
                        'pixels_used': int(r.pixels_used), 'elapsed_s': r.elapsed_s})
        return EXIT_OK if ok else EXIT_FAILED

    def report():
        if not answers:  # the node did not answer
            return
        (answer,) = answers
        if args.json:
            print(json.dumps(answer))
        elif answer['success']:
            print(format_calibration(answer))
            if 'WARNING' in answer['message']:
                print(answer['message'][answer['message'].index('WARNING'):], file=sys.stderr)
        else:
            print(f'calibration {answer["status"]}: {answer["message"]}', file=sys.stderr)

    return _run(args, 'calibrate', params, calibrate, report)
