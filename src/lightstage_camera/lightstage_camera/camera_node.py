"""The camera node: one ``/image_raw`` frame per light-stage trigger, stamped with that trigger.

Subscribes ``/illumination`` (`IlluminationState`, one per trigger), hands each trigger to a
camera backend (`camera_backend.CameraBackend`) and publishes the frame it delivers as
``sensor_msgs/Image`` ``mono16`` with ``header.stamp`` = the trigger stamp (acquisition
time), so that a consumer matches images to patterns by stamp, never by arrival order.

Backend ``sim`` (`sim_camera.SimCameraBackend`) renders the sample "on the stage" (parameter
``sample``, changeable at run time) from a capture folder. A missing capture folder or an
unknown sample leaves the node up, logging the error and reporting it on ``/diagnostics``.
"""
from __future__ import annotations

import sys

from dataclasses import replace

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from lightstage_interfaces.msg import IlluminationState
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from .camera_backend import Frame, Trigger
from .frames import stamp_to_ns
from .noise import PAPER_CALIBRATION, NoiseModel, load_noise_file
from .sim_camera import NOISE_CHOICES, SimCameraBackend, parse_noise, resolve_sample
from .spinning import spin_until_stopped

NODE_NAME = 'camera'
IMAGE_TOPIC = '/image_raw'
ILLUMINATION_TOPIC = '/illumination'
BACKENDS = ('sim',)

# Reliable, keep-last 32 (not SensorData's best-effort depth 5): the classifier needs every
# frame of a trigger sequence and matches them by stamp, so a dropped frame is a failed
# classification, not a skipped video frame. 32 frames cover one full 32-pattern sequence.
IMAGE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32,
                       reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
# as the driver publishes /illumination: reliable, depth 100
ILLUMINATION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)


def _text(description: str, *, read_only: bool = False, constraints: str = '',
          dynamic: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_STRING, description=description,
                               read_only=read_only, additional_constraints=constraints,
                               dynamic_typing=dynamic)


PARAMETERS = {
    'backend': ('sim', _text('camera backend; sim renders the sample on the stage from a capture '
                             'folder', read_only=True, constraints='one of: ' + ', '.join(BACKENDS))),
    'capture_dir': ('', _text('capture folder (rig.yaml + <label>/<sample>/<pose>/) the sim '
                              'backend renders from; settable at run time (reloads)')),
    'sample': ('0', _text('sample on the stage: a name label/sample/pose (e.g. banana-fake/s2/p03) '
                          'or an index; settable at run time', dynamic=True)),
    'noise': ('auto', _text('camera noise: auto = from each trigger\'s gain_db and exposure_us '
                            '(affine model at the paper\'s calibration, or at noise_file\'s), a '
                            'fixed preset, or none',
                            constraints='one of: ' + ', '.join(NOISE_CHOICES))),
    'noise_file': ('', _text('calibrated noise file (YAML written by `lightstage calibrate`) that '
                             'noise auto generalizes to each trigger\'s gain and exposure instead '
                             'of the paper\'s 15 dB / 30 ms fit; empty = the paper\'s')),
    'seed': (-1, ParameterDescriptor(type=ParameterType.PARAMETER_INTEGER,
                                     description='noise seed; -1 = fresh entropy',
                                     integer_range=[IntegerRange(from_value=-1, to_value=2**31 - 1, step=1)])),
    'frame_id': ('camera', _text('frame_id of the published images')),
    'dimmer': (0.45, ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE,
                                         description='scale of the single-LED images before '
                                                     'multiplexing (the authors\' 0.45)',
                                         floating_point_range=[FloatingPointRange(from_value=0.001, to_value=10.0)])),
    'default_gain_db': (15.0, ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE,
        description='gain [dB] for triggers that ask for the camera default (gain_db NaN)',
        floating_point_range=[FloatingPointRange(from_value=0.0, to_value=48.0)])),
    'diagnostics_period_s': (1.0, ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE, description='/diagnostics period [s]', read_only=True,
        floating_point_range=[FloatingPointRange(from_value=0.1, to_value=60.0)])),
}
BACKEND_SETTINGS = ('capture_dir', 'sample', 'noise', 'noise_file', 'seed', 'dimmer',
                    'default_gain_db')


def noise_calibration(noise_file: str) -> NoiseModel:
    """The fit `noise: auto` generalizes: the noise file's, or the paper's (empty path)."""
    return load_noise_file(noise_file) if str(noise_file).strip() else PAPER_CALIBRATION


def ns_to_stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def trigger_from_message(msg: IlluminationState) -> Trigger:
    return Trigger(stamp_ns=stamp_to_ns(msg.header.stamp), sequence=int(msg.sequence),
                   led_intensities=np.asarray(msg.intensities, dtype=np.float32),
                   exposure_us=int(msg.exposure_us), gain_db=float(msg.gain_db))


def image_message(frame: Frame, frame_id: str) -> Image:
    """``mono16`` Image of a frame, stamped with its trigger (acquisition time)."""
    image = np.ascontiguousarray(frame.image, dtype=np.uint16)
    msg = Image()
    msg.header.stamp = ns_to_stamp(frame.trigger.stamp_ns)
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(image.shape[0]), int(image.shape[1])
    msg.encoding = 'mono16'
    msg.is_bigendian = int(sys.byteorder == 'big')
    msg.step = 2 * msg.width
    msg.data = image.tobytes()
    return msg


class CameraNode(Node):
    def __init__(self, node_name: str = NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        for name, (default, descriptor) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor)
        self.backend = None
        self.error = ''
        self.published = 0
        self.dropped = 0
        self._image_pub = self.create_publisher(Image, IMAGE_TOPIC, IMAGE_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._start_backend(self._settings())
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_subscription(IlluminationState, ILLUMINATION_TOPIC, self._on_illumination,
                                 ILLUMINATION_QOS)
        self.create_timer(self.p('diagnostics_period_s'), self._publish_diagnostics)
        self._publish_diagnostics()

    def p(self, name: str):
        return self.get_parameter(name).value

    def _settings(self, changes: dict | None = None) -> dict:
        settings = {name: self.p(name) for name in BACKEND_SETTINGS}
        settings.update(changes or {})
        return settings

    # ------------------------------------------------------------------ backend
    def _make_backend(self, s: dict) -> SimCameraBackend:
        """A backend for the settings `s`; raises ValueError/OSError saying what is wrong.

        A real camera backend (its own module implementing `CameraBackend`) is chosen here by
        the `backend` parameter; the `sim`-only settings would then not apply to it.
        """
        backend = self.p('backend')
        if backend not in BACKENDS:
            raise ValueError(f'unknown backend {backend!r}; this node has {", ".join(BACKENDS)}')
        if not str(s['capture_dir']).strip():
            raise ValueError('no capture folder: set the capture_dir parameter to a folder with '
                             'rig.yaml (e.g. one written by `lightstage synth`)')
        seed = None if int(s['seed']) < 0 else int(s['seed'])
        return SimCameraBackend.from_capture(
            self._publish_frame, s['capture_dir'], sample=s['sample'], noise=s['noise'],
            dimmer=float(s['dimmer']), default_gain_db=float(s['default_gain_db']), seed=seed,
            calibration=noise_calibration(s['noise_file']))

    def _start_backend(self, s: dict) -> None:
        try:
            self.backend = self._make_backend(s)
        except (ValueError, OSError) as exc:
            self.backend = None
            self.error = f'camera not ready: {exc}'
            self.get_logger().error(self.error)
            return
        self.error = ''
        cam = self.backend.camera
        self.get_logger().info(
            f'sim camera on {s["capture_dir"]}: {len(cam.modelset)} samples, '
            f'{cam.image_shape[1]}x{cam.image_shape[0]} px, {cam.bit_depth}-bit, noise {s["noise"]}'
            f'{" calibrated by " + s["noise_file"] if str(s["noise_file"]).strip() else ""}; '
            f'sample {cam.sample_name} on the stage')

    def _on_set_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params if p.name in BACKEND_SETTINGS}
        if not changes:
            return SetParametersResult(successful=True)
        s = self._settings(changes)
        try:
            parse_noise(s['noise'])
            # the noise file is read when it is named, not again on every other change (a
            # file moved since must not make e.g. a sample change fail)
            calibration = noise_calibration(s['noise_file']) if 'noise_file' in changes else None
            if self.backend is None:
                # not running: take the value and retry, so settings can be fixed one by one
                # (the remaining problem, if any, goes to the log and /diagnostics)
                self._start_backend(s)
                return SetParametersResult(successful=True)
            if 'capture_dir' in changes:
                new = self._make_backend(s)  # the working backend stays if this fails
                self.backend.close()
                self.backend, self.error = new, ''
                self.get_logger().info(f'loaded {s["capture_dir"]}; sample {new.camera.sample_name} '
                                       'on the stage')
                return SetParametersResult(successful=True)
            cam = self.backend.camera
            index = resolve_sample(cam.modelset, s['sample'])  # validate before changing anything
            cam.sample_index, cam.noise = index, parse_noise(s['noise'])
            if calibration is not None:
                cam.calibration = replace(calibration, max_level=cam.modelset.max_level)
            cam.dimmer = float(s['dimmer'])
            cam.default_gain_db = float(s['default_gain_db'])
            if 'seed' in changes:
                cam.rng = np.random.default_rng(None if int(s['seed']) < 0 else int(s['seed']))
        except (ValueError, OSError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if 'sample' in changes:
            self.get_logger().info(f'sample {cam.sample_name} on the stage')
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ frames
    def _on_illumination(self, msg: IlluminationState) -> None:
        if self.backend is None:
            self.dropped += 1
            self.get_logger().warning(f'trigger {msg.sequence} not imaged: {self.error}',
                                      throttle_duration_sec=5.0)
            return
        try:
            self.backend.trigger(trigger_from_message(msg))
        except ValueError as exc:
            self.dropped += 1
            self.error = f'trigger {msg.sequence} not imaged: {exc}'
            self.get_logger().error(self.error)

    def _publish_frame(self, frame: Frame) -> None:
        self._image_pub.publish(image_message(frame, self.p('frame_id')))
        self.published += 1

    # ------------------------------------------------------------------ health
    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name=f'{self.get_name()}: camera', hardware_id=str(self.p('backend')))
        values = {'backend': self.p('backend'), 'capture_dir': self.p('capture_dir'),
                  'images_published': self.published, 'triggers_dropped': self.dropped,
                  'last_error': self.error}
        if self.backend is None:
            status.level, status.message = DiagnosticStatus.ERROR, self.error
        else:
            health = self.backend.status()
            values.update(health.values)
            if health.ok and not self.error:
                status.level, status.message = DiagnosticStatus.OK, health.message
            else:
                status.level = DiagnosticStatus.ERROR if not health.ok else DiagnosticStatus.WARN
                status.message = health.message if not health.ok else self.error
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def destroy_node(self):
        if self.backend is not None:
            self.backend.close()
        return super().destroy_node()


def main(argv: list[str] | None = None) -> int:
    from .spinning import init_node
    init_node(sys.argv if argv is None else argv)
    return spin_until_stopped(CameraNode())

if __name__ == '__main__':
    sys.exit(main())
