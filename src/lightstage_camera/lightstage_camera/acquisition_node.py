"""The acquisition node: model capture and noise calibration on the stage, as actions.

``/lightstage/capture_model`` (CaptureModel) captures the relightable model of the sample on
the stage into a capture folder (`acquisition.capture_model` + `acquisition.write_model`);
``/lightstage/calibrate_noise`` (CalibrateNoise) characterizes the camera noise on a
calibration target (`calibration.calibrate_noise`) and writes a noise file and a plot.

Both light patterns through the driver's ``/lightstage/apply_patterns`` (``trigger: true``,
one camera trigger per pattern) and collect the ``camera/image_raw`` frames whose header stamps
equal the returned trigger stamps (`lightstage_graph.stage_client`, as the classifier
does), in requests of at most ``frames_per_request`` frames. One goal at a time (they share the
stage): a goal that arrives while another runs is rejected. A goal's work waits for the
driver and the images, so it runs on a worker thread of its own and the goal's handler, a
coroutine, awaits it (`lightstage_graph.awaitable`): no callback blocks, and the node spins
one executor thread, which takes each image once (on a MultiThreadedExecutor every free
thread re-dispatched a ready image until one took it: docs/NODES.md).
"""
from __future__ import annotations

import math
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timezone

from lightstage_graph.awaitable import executor_future
from lightstage_graph.errors import StageError
from lightstage_graph.limits import (EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN,
                                    requested_gain_db)
from lightstage_graph.names import ACQUISITION_NODE, CALIBRATE_ACTION, CAPTURE_ACTION
from lightstage_graph.params import boolean, declare_parameters, floating, integer, string
from lightstage_graph.spin import init_node, spin_until_stopped
from lightstage_graph.stage_client import StageClient
from lightstage_interfaces.action import CalibrateNoise, CaptureModel
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from lightstage_physics.rig import MAX_FRAMES_AVERAGED, N_SITES, Rig

from .acquisition import CaptureCancelled, DestinationError, acquire_pose
from .calibration import CalibrationSettings, calibrate_noise
from .calibration_outputs import check_calibration_outputs, write_calibration_outputs
from .capture_settings import CaptureSettings

START_HINT = 'lightstage up driver camera acquisition'

PARAMETERS = {
    'exposure_us': (30000, integer('model capture: exposure per frame [us] for goals with '
                                   'exposure_us 0 (long: models should be low-noise)',
                                   EXPOSURE_US_MIN, EXPOSURE_US_MAX)),
    'gain_db': (15.0, floating('model capture: camera gain [dB] for goals without one (gain_db '
                               '0 with gain_db_set false, as a field left out comes, or NaN)',
                               GAIN_DB_MIN, GAIN_DB_MAX)),
    'frames_averaged': (16, integer('model capture: frames averaged per single-LED image for '
                                    'goals with frames_averaged 0', 1, MAX_FRAMES_AVERAGED)),
    'max_saturated_fraction': (0.0, floating(
        'model capture: the exposure preview (one frame per LED) refuses the capture when an LED '
        'image has more than this fraction of its pixels at the camera\'s maximum', 0.0, 1.0)),
    'preview': (True, boolean(
        'model capture: take one frame per LED first to check the exposure (and the image size '
        'against the folder) before the long capture')),
    'rig_file': ('', string(
        'rig.yaml describing the stage\'s sites for new capture folders (its camera section is '
        'replaced by the capture\'s setting); empty = an existing folder\'s own rig.yaml, or the '
        'paper\'s stage for a new folder')),
    'calibration_exposure_us': (30000, integer('noise calibration: exposure per frame [us] for '
                                               'goals with exposure_us 0 (the paper: 30 ms)',
                                               EXPOSURE_US_MIN, EXPOSURE_US_MAX)),
    'calibration_gain_db': (15.0, floating('noise calibration: gain [dB] for goals without one '
                                           '(gain_db 0 with gain_db_set false, or NaN; the paper: '
                                           '15 dB)', GAIN_DB_MIN, GAIN_DB_MAX)),
    'calibration_frames': (120, integer('noise calibration: frames per illumination level for '
                                        'goals with frames_per_level 0 (the paper: 120; >= 3: '
                                        'the fit splits them in two halves)', 3, 100_000)),
    'calibration_levels': (8, integer('noise calibration: illumination levels for goals with '
                                      'levels 0', 2, 4 * N_SITES)),
    'frames_per_request': (16, integer('frames per driver request (one trigger sequence); at most '
                                       'the camera\'s image queue (32)', 1, 32)),
    'camera_bit_depth': (10, integer('significant bits of the camera\'s mono16 images', 8, 16)),
    'timeout_s': (10.0, floating('time limit of one driver request and its images, on top of '
                                 'their exposures [s]', 0.1, 600.0)),
    'image_buffer': (64, integer('images kept while waiting for their trigger stamps', 32, 1024,
                                 read_only=True)),
}


def _or_default(value, default):
    """Goal field value, or the node's default when the field is 0 (counts, exposures)."""
    return value if value else default


def _gain_or_default(goal, default: float) -> float:
    """The goal's gain [dB], or the node's: a goal that leaves gain_db out (0 with gain_db_set
    false, what `ros2 action send_goal` fills in) or gives NaN gets the node's gain."""
    gain = requested_gain_db(goal.gain_db, goal.gain_db_set)
    return float(default) if math.isnan(gain) else gain


class AcquisitionNode(Node):
    def __init__(self, node_name: str = ACQUISITION_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        self._busy = threading.Lock()  # one goal at a time: the stage is shared
        # a goal's work: off the executor thread (it waits for the driver and the images)
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix='acquisition')
        self._stopping = threading.Event()
        group = ReentrantCallbackGroup()
        self.stage = StageClient(self, image_buffer=self.p('image_buffer'), callback_group=group,
                                 start_hint=START_HINT)
        self._capture_server = ActionServer(
            self, CaptureModel, CAPTURE_ACTION, execute_callback=self._execute_capture,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel, callback_group=group)
        self._calibrate_server = ActionServer(
            self, CalibrateNoise, CALIBRATE_ACTION, execute_callback=self._execute_calibration,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel, callback_group=group)

    # ------------------------------------------------------------------ the stage
    def _wait_for_stage(self) -> None:
        self.stage.wait_ready(float(self.p('timeout_s')))

    def _grabber(self, exposure_us: int, gain_db: float):
        """grab(led_patterns (32, k)) -> k mono16 frames, matched by trigger stamp; each
        request may take `timeout_s` on top of its exposures."""
        def grab(patterns) -> list:
            limit_s = float(self.p('timeout_s')) + patterns.shape[1] * exposure_us / 1e6
            return self.stage.grab(patterns, exposure_us, gain_db, limit_s)
        return grab

    # ------------------------------------------------------------------ goals
    def _on_goal(self, _goal) -> GoalResponse:
        if self._busy.locked():
            self.get_logger().warning('goal rejected: a capture or calibration is running on '
                                      'the stage')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_cancel(self, _goal_handle) -> CancelResponse:
        return CancelResponse.ACCEPT

    def stop_work(self):
        """At the node's stop (`spin_until_stopped`): a running goal ends at its next
        cancellation check, aborted; returns whether no goal runs any more."""
        self._stopping.set()
        return lambda: not self._busy.locked()

    def destroy_node(self) -> None:
        self._stopping.set()
        self._worker.shutdown(wait=False, cancel_futures=True)
        super().destroy_node()

    def _cancelled(self, goal_handle) -> bool:
        """Whether the goal's work should end: a cancel request, or the node stopping."""
        return goal_handle.is_cancel_requested or self._stopping.is_set()

    async def _on_stage(self, goal_handle, result, cancelled: str, failed: str, work):
        """End the goal with `work(start)`, run on the worker thread with the stage to itself
        (one goal at a time) while this handler awaits it: it fills `result` and returns the
        message of success. A cancellation ends the goal as cancelled (`cancelled: why`), an
        acquisition error, bad value or I/O error as aborted (`failed: why`)."""
        start = time.perf_counter()
        if not self._busy.acquire(blocking=False):
            return self._finish(goal_handle, result, 'abort', 'another capture or calibration '
                                'is running on the stage; try again when it is done', start)

        def run() -> tuple[str, str]:
            try:
                return 'succeed', work(start)
            except CaptureCancelled as exc:
                if self._stopping.is_set():
                    return 'abort', f'{failed}: the acquisition node is stopping'
                return 'cancel', f'{cancelled}: {exc}'
            except (StageError, ValueError, OSError) as exc:  # AcquisitionError: a StageError
                return 'abort', f'{failed}: {exc}'
            finally:
                self._busy.release()

        try:
            queued = self._worker.submit(run)
        except RuntimeError:   # the node is being destroyed: the worker takes no more work
            queued = None
        finished = None if queued is None else await executor_future(self, queued)
        if finished is None or finished.cancelled():   # `run` never ran
            self._busy.release()
            return self._finish(goal_handle, result, 'abort', f'{failed}: the acquisition '
                                'node is stopping', start)
        verdict, message = finished.result()
        return self._finish(goal_handle, result, verdict, message, start)

    def _finish(self, goal_handle, result, outcome: str, message: str, start: float):
        result.message = message
        result.elapsed_s = time.perf_counter() - start
        if outcome == 'succeed':
            result.success = True
            goal_handle.succeed()
            self.get_logger().info(message)
        elif outcome == 'cancel':
            goal_handle.canceled()
            self.get_logger().info(message)
        else:
            goal_handle.abort()
            self.get_logger().error(message)
        return result

    # ------------------------------------------------------------------ CaptureModel
    def _capture_settings(self, goal) -> CaptureSettings:
        return CaptureSettings(
            exposure_us=int(_or_default(int(goal.exposure_us), self.p('exposure_us'))),
            gain_db=_gain_or_default(goal, self.p('gain_db')),
            frames=int(_or_default(int(goal.frames_averaged), self.p('frames_averaged'))),
            bit_depth=int(self.p('camera_bit_depth')), n_sites=N_SITES,
            frames_per_request=int(self.p('frames_per_request')),
            max_saturated_fraction=float(self.p('max_saturated_fraction')))

    def _base_rig(self) -> Rig | None:
        path = str(self.p('rig_file')).strip()
        if not path:
            return None
        try:
            return Rig.load_yaml(path)
        except Exception as exc:  # noqa: BLE001 - missing file, YAML errors, bad values
            raise DestinationError(f'rig_file {path} does not load ({exc}); fix it or set '
                                   'rig_file to \'\' (the paper\'s stage)') from None

    async def _execute_capture(self, goal_handle):
        goal = goal_handle.request
        result = CaptureModel.Result()
        name = f'{goal.label}/{goal.sample}/{goal.pose}'

        def capture(start: float) -> str:
            settings = self._capture_settings(goal)

            def progress(done: int, total: int, led: str, stage: str) -> None:
                goal_handle.publish_feedback(CaptureModel.Feedback(
                    images_done=done, images_total=total, current_led=led, stage=stage))

            self.get_logger().info(f'capturing {name} into {goal.output_dir}: {settings.n_leds} '
                                   f'LED images x {settings.frames} frames at '
                                   f'{settings.exposure_us} us, {settings.gain_db:g} dB')
            pose_dir, captured = acquire_pose(
                self._grabber(settings.exposure_us, settings.gain_db), settings,
                goal.output_dir, goal.label, goal.sample, goal.pose, base_rig=self._base_rig(),
                overwrite=goal.overwrite, preview=bool(self.p('preview')),
                cancelled=lambda: self._cancelled(goal_handle),
                before_capture=self._wait_for_stage,
                on_progress=progress)
            result.model_dir = str(pose_dir)
            result.images_captured = settings.n_leds
            result.saturated_pixels = captured.saturated_pixels
            warning = captured.saturation_warning()
            message = (f'wrote {pose_dir}: {settings.n_leds} LED images x {settings.frames} '
                       f'frames in {time.perf_counter() - start:.1f} s')
            if warning:
                message += f'; WARNING: {warning}'
                self.get_logger().warning(warning)
            return message

        return await self._on_stage(goal_handle, result, name, f'capture of {name} failed',
                                    capture)

    # ------------------------------------------------------------------ CalibrateNoise
    def _calibration_settings(self, goal) -> CalibrationSettings:
        return CalibrationSettings(
            exposure_us=int(_or_default(int(goal.exposure_us), self.p('calibration_exposure_us'))),
            gain_db=_gain_or_default(goal, self.p('calibration_gain_db')),
            frames_per_level=int(_or_default(int(goal.frames_per_level),
                                             self.p('calibration_frames'))),
            levels=int(_or_default(int(goal.levels), self.p('calibration_levels'))),
            bit_depth=int(self.p('camera_bit_depth')), n_sites=N_SITES,
            frames_per_request=int(self.p('frames_per_request')))

    async def _execute_calibration(self, goal_handle):
        goal = goal_handle.request
        result = CalibrateNoise.Result()

        def calibrate(_start: float) -> str:
            settings = self._calibration_settings(goal)
            check_calibration_outputs(goal.output_path, goal.plot_path, goal.overwrite)
            self._wait_for_stage()
            grab = self._grabber(settings.exposure_us, settings.gain_db)

            def feedback(level, levels, done, total, lit) -> None:
                goal_handle.publish_feedback(CalibrateNoise.Feedback(
                    level=level, levels=levels, frames_done=done, frames_total=total,
                    leds_lit=lit, stage='capturing'))

            def stage(name: str) -> None:
                goal_handle.publish_feedback(CalibrateNoise.Feedback(
                    level=settings.levels, levels=settings.levels, stage=name))

            self.get_logger().info(
                f'calibrating noise: {settings.levels} levels x {settings.frames_per_level} '
                f'frames at {settings.exposure_us} us, {settings.gain_db:g} dB')
            calibration = calibrate_noise(grab, settings, on_frames=feedback,
                                          on_fitting=lambda: stage('fitting'),
                                          cancelled=lambda: self._cancelled(goal_handle))
            # the fit goes into the result first: a failed write still returns it
            fit = calibration.model
            result.sigma_p2, result.sigma_r2 = float(fit.sigma_p2), float(fit.sigma_r2)
            result.sigma_p2_stderr, result.sigma_r2_stderr = map(float, calibration.stderr)
            result.gain_db, result.exposure_ms = float(fit.gain_db), float(fit.exposure_ms)
            result.pixels_used = calibration.pixels_used
            stage('writing')
            result.output_path, result.plot_path = write_calibration_outputs(
                calibration, goal.output_path, goal.plot_path, overwrite=goal.overwrite,
                measured_at=datetime.now(timezone.utc).isoformat(timespec='seconds'))
            message = (f'variance = {fit.sigma_p2:.4g} (+-{calibration.stderr[0]:.2g}) * mean + '
                       f'{fit.sigma_r2:.4g} (+-{calibration.stderr[1]:.2g}) at {fit.gain_db:g} dB, '
                       f'{fit.exposure_ms:g} ms from {calibration.pixels_used} pixels x '
                       f'{settings.frames_per_level} frames')
            for warning in calibration.warnings():
                message += f'; WARNING: {warning}'
            return message

        return await self._on_stage(goal_handle, result, 'noise calibration',
                                    'noise calibration failed', calibrate)


def main(argv: list[str] | None = None) -> int:
    init_node(sys.argv if argv is None else argv)
    return spin_until_stopped(AcquisitionNode(), SingleThreadedExecutor())


if __name__ == '__main__':
    sys.exit(main())
