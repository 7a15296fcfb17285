"""The camera node: one ``camera/image_raw`` frame per light-stage trigger, stamped with that
trigger.

Subscribes ``/illumination`` (`IlluminationState`, one per trigger), hands each trigger to a
camera backend (`camera_backend.CameraBackend`) and publishes the frame it delivers as
``sensor_msgs/Image`` ``mono16`` with ``header.stamp`` = the trigger stamp (acquisition
time), so that a consumer matches images to patterns by stamp, never by arrival order.
Every image goes with a ``sensor_msgs/CameraInfo`` (same header) on ``camera/camera_info``,
from ``camera_info_url`` (camera_calibration's YAML) or uncalibrated.

Backends ``basler`` (pypylon) and ``aravis`` (any GenICam camera) drive a real camera
(`triggered_backend`); a trigger whose frame is lost (failed buffer, BlockID gap, no frame,
camera unplugged) publishes no image but a ``FrameLost`` on ``camera/frame_lost`` (the
trigger's stamp and sequence, and why), so that whoever waits for that frame fails at once
naming the cause; it is also logged, counted and reported on ``/diagnostics``, and the camera
is reopened after a fault without restarting the node. The topics are relative, in the
camera's namespace as ROS camera drivers put them, and remappable.

A trigger whose values no camera takes (a gain outside 0 .. 48 dB other than NaN, an
exposure out of range, LED values that are not in 0 .. 1: `lightstage_graph.limits`), or
that the backend fails on, is a lost frame too, with the reason naming the field
(`camera_backend.hand_trigger`): no value a request carries stops the node.

Backend ``sim`` (`sim_camera.SimCameraBackend`) renders the sample "on the stage" (parameter
``sample``, changeable at run time) from a capture folder. A missing capture folder or an
unknown sample leaves the node up, logging the error and reporting it on ``/diagnostics``.
"""
from __future__ import annotations

import sys

from dataclasses import replace

import numpy as np
from lightstage_graph.diagnostics import ERROR, OK, WARN, DiagnosticsPublisher, Report
from lightstage_graph.limits import (DIMMER_MIN, DIMMER_MAX, EXPOSURE_US_MAX, EXPOSURE_US_MIN,
                                     GAIN_DB_MAX, GAIN_DB_MIN)
from lightstage_graph.links import ReaderMatch
from lightstage_graph.names import (CAMERA_INFO_TOPIC, CAMERA_NODE, FRAME_LOST_TOPIC,
                                    ILLUMINATION_TOPIC, IMAGE_TOPIC)
from lightstage_graph.params import boolean, declare_parameters, floating, integer, string
from lightstage_graph.qos import ILLUMINATION_QOS, IMAGE_QOS
from lightstage_graph.spin import init_node, spin_until_stopped
from lightstage_graph.stamps import ns_to_stamp, stamp_to_ns
from lightstage_interfaces.msg import FrameLost, IlluminationState
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from .camera_backend import CameraBackend, Frame, LostFrame, Trigger, hand_trigger
from .camera_info import Calibration, load_calibration
from lightstage_physics.noise import PAPER_CALIBRATION, NoiseModel, load_noise_file
from lightstage_physics.rig import DEFAULT_DIMMER
from .sim_camera import NOISE_CHOICES, SimCameraBackend, parse_noise, resolve_sample
from .triggered_backend import PIXEL_FORMATS, parse_features

BACKENDS = ('sim', 'basler', 'aravis')
TRIGGER_SOURCES = ('Line1', 'Line2', 'Line3', 'Line4', 'Software')


PARAMETERS = {
    'backend': ('sim', string('camera backend: sim renders the sample on the stage from a capture '
                              'folder; basler (pypylon) and aravis (GenICam: GigE Vision, USB3 '
                              'Vision) drive a real camera', read_only=True,
                              constraints='one of: ' + ', '.join(BACKENDS))),
    'capture_dir': ('', string('capture folder (rig.yaml + <label>/<sample>/<pose>/) the sim '
                               'backend renders from; settable at run time (reloads)')),
    'sample': ('0', string('sample on the stage: a name label/sample/pose (e.g. '
                           'banana-fake/s2/p03) or an index; settable at run time',
                           dynamic=True)),
    'noise': ('auto', string('camera noise: auto = from each trigger\'s gain_db and exposure_us '
                             '(affine model at the paper\'s calibration, or at noise_file\'s), a '
                             'fixed preset, or none',
                             constraints='one of: ' + ', '.join(NOISE_CHOICES))),
    'noise_file': ('', string('calibrated noise file (YAML written by `lightstage calibrate`) that '
                              'noise auto generalizes to each trigger\'s gain and exposure instead '
                              'of the paper\'s 15 dB / 30 ms fit; empty = the paper\'s')),
    'seed': (-1, integer('noise seed; -1 = fresh entropy', -1, 2**31 - 1)),
    'frame_id': ('camera', string('frame_id of the published images')),
    'dimmer': (DEFAULT_DIMMER, floating('scale of the single-LED images before multiplexing '
                                        f'(the authors\' {DEFAULT_DIMMER})', DIMMER_MIN, DIMMER_MAX)),
    'default_gain_db': (15.0, floating('gain [dB] for triggers that ask for the camera default '
                                       '(gain_db NaN)', GAIN_DB_MIN, GAIN_DB_MAX)),
    'exposure_scales_light': (False, boolean('sim: the image is the light integrated over each '
                                             'trigger\'s exposure (times exposure_us / the rig\'s '
                                             'exposure_us), as on a graded stage where a level is '
                                             'an LED\'s share of the exposure; false = the '
                                             'authors\' convention, exposure changes only the noise')),
    # ---- real cameras (basler, aravis)
    'serial_number': ('', string('camera to open: basler: serial number; aravis: device id, serial '
                                 'or IP address (opened by address: no discovery); empty = the '
                                 'first camera found')),
    'trigger_source': ('Line1', string('TriggerSource: Line1 = the stage\'s trigger pin wired to '
                                       'the camera (exposure = pulse width where the camera has '
                                       'TriggerWidth); Software = the node fires each trigger '
                                       'when it is announced (emulators, tests)',
                                       constraints='one of: ' + ', '.join(TRIGGER_SOURCES))),
    'pixel_format': ('Mono10', string('PixelFormat; published as mono16 MSB-aligned (10-bit v -> '
                                      'v << 6), the bit depth is on /diagnostics',
                                      constraints='one of: ' + ', '.join(PIXEL_FORMATS))),
    'exposure_us': (30000.0, floating('exposure [us] for triggers that carry none; the camera\'s '
                                      'value is read back and reported as exposure_us_actual on '
                                      '/diagnostics', EXPOSURE_US_MIN, EXPOSURE_US_MAX)),
    'gain_db': (15.0, floating('gain [dB] for triggers that ask for the camera default (gain_db '
                               'NaN); read back and reported as gain_db_actual on /diagnostics',
                               GAIN_DB_MIN, GAIN_DB_MAX)),
    'camera_info_url': ('', string('camera calibration (the YAML camera_calibration writes): '
                                   'file:///path/camera.yaml, a path or package://pkg/path; '
                                   'empty = uncalibrated camera_info')),
    'transport_layer': ('', string('basler: search only this pylon transport layer (BaslerCamEmu = '
                                   'the emulated cameras, no network discovery); empty = all')),
    'camera_features': ('', string('extra GenICam settings applied in order after the node\'s '
                                   'own, when the camera opens: "Name=Value; Command; ..." '
                                   '(e.g. "UserSetSelector=UserSet1; UserSetLoad; '
                                   'LineDebouncerTime=10")')),
    'frame_timeout_s': (1.0, floating('time a trigger may wait for its frame on top of its '
                                      'exposure [s]; then it is reported lost (grab timeout)',
                                      0.01, 60.0)),
    'reopen_period_s': (1.0, floating('while the camera is missing or after a fault: time between '
                                      'attempts to open it [s]', 0.1, 60.0)),
    'diagnostics_period_s': (1.0, floating('/diagnostics period [s]', 0.1, 60.0, read_only=True)),
}
BACKEND_SETTINGS = ('capture_dir', 'sample', 'noise', 'noise_file', 'seed', 'dimmer',
                    'default_gain_db', 'exposure_scales_light')
# real cameras: a change of these reopens the camera; exposure and gain apply at once
CAMERA_SETTINGS = ('serial_number', 'trigger_source', 'pixel_format', 'transport_layer',
                   'camera_features', 'frame_timeout_s', 'reopen_period_s')
LIVE_CAMERA_SETTINGS = ('exposure_us', 'gain_db')
# what each kind of backend uses; a change of another kind's parameter is refused with the
# reason (the backend is read-only: chosen at start-up), not taken and ignored
REAL_CAMERA_ONLY = CAMERA_SETTINGS + LIVE_CAMERA_SETTINGS
SIM_ONLY = BACKEND_SETTINGS


def other_backend_refusal(names, backend: str) -> str:
    """The reason a change of `names` is refused on a `backend` camera node: those parameters
    only the other kind of backend uses ('' when none)."""
    sim = backend == 'sim'
    foreign = sorted(n for n in names if n in (REAL_CAMERA_ONLY if sim else SIM_ONLY))
    if not foreign:
        return ''
    used_by = 'the real-camera backends (basler, aravis)' if sim else 'the sim backend'
    return (f'{", ".join(foreign)}: used only by {used_by}, and this camera node runs the '
            f'{backend} backend (backend is chosen at start-up)')


def noise_calibration(noise_file: str) -> NoiseModel:
    """The fit `noise: auto` generalizes: the noise file's, or the paper's (empty path)."""
    return load_noise_file(noise_file) if str(noise_file).strip() else PAPER_CALIBRATION


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


def camera_info_message(header, calibration: Calibration) -> CameraInfo:
    """``CameraInfo`` for an image with `header` (the same header: stamp and frame_id)."""
    msg = CameraInfo(header=header, width=calibration.width, height=calibration.height,
                     distortion_model=calibration.distortion_model)
    msg.d = [float(v) for v in calibration.d]
    msg.k, msg.r, msg.p = list(calibration.k), list(calibration.r), list(calibration.p)
    return msg


def split_features(text: str) -> list[str]:
    """``"A=1; B=2"`` -> ``["A=1", "B=2"]`` (the camera_features parameter)."""
    return [part.strip() for part in str(text).split(';') if part.strip()]


class CameraNode(Node):
    def __init__(self, node_name: str = CAMERA_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        self.backend: CameraBackend | None = None
        self.error = ''
        self.published = 0
        self.dropped = 0
        self.calibration: Calibration | None = None
        self.calibration_error = ''
        self._image_pub = self.create_publisher(Image, IMAGE_TOPIC, IMAGE_QOS)
        self._info_pub = self.create_publisher(CameraInfo, CAMERA_INFO_TOPIC, IMAGE_QOS)
        self._lost_pub = self.create_publisher(FrameLost, FRAME_LOST_TOPIC, IMAGE_QOS)
        # a reader that just subscribed (a classifier right after start-up) gets the next frame
        self._image_readers = ReaderMatch(self, self._image_pub)
        self._lost_readers = ReaderMatch(self, self._lost_pub)
        # subscribed before the backend starts (a capture can take seconds to load): a client
        # that sees the image publisher finds this reader in the graph too, so the driver's
        # wait for /illumination's readers includes it; triggers meanwhile queue until spin
        self.create_subscription(IlluminationState, ILLUMINATION_TOPIC, self._on_illumination,
                                 ILLUMINATION_QOS)
        try:
            self._load_calibration(self.p('camera_info_url'))
        except (ValueError, OSError) as exc:
            self.calibration_error = f'camera_info_url: {exc}; publishing an uncalibrated camera_info'
            self.get_logger().error(self.calibration_error)
        self._start_backend(self._settings())
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.diagnostics = DiagnosticsPublisher(self, 'camera', self._camera_status,
                                                self.p('diagnostics_period_s'))
        self.diagnostics.publish()

    @property
    def real_camera(self) -> bool:
        return self.p('backend') != 'sim'

    def _settings(self, changes: dict | None = None) -> dict:
        names = (CAMERA_SETTINGS + LIVE_CAMERA_SETTINGS) if self.real_camera else BACKEND_SETTINGS
        settings = {name: self.p(name) for name in names}
        settings.update(changes or {})
        return settings

    # ------------------------------------------------------------------ backend
    def _make_backend(self, s: dict) -> CameraBackend:
        """A backend for the settings `s`; raises ValueError/OSError saying what is wrong."""
        backend = self.p('backend')
        if backend not in BACKENDS:
            raise ValueError(f'unknown backend {backend!r}; this node has {", ".join(BACKENDS)}')
        if backend != 'sim':
            return self._make_camera_backend(backend, s)
        if not str(s['capture_dir']).strip():
            raise ValueError('no capture folder: set the capture_dir parameter to a folder with '
                             'rig.yaml (e.g. one written by `lightstage synth`)')
        seed = None if int(s['seed']) < 0 else int(s['seed'])
        return SimCameraBackend.from_capture(
            self._publish_frame, s['capture_dir'], sample=s['sample'], noise=s['noise'],
            dimmer=float(s['dimmer']), default_gain_db=float(s['default_gain_db']), seed=seed,
            calibration=noise_calibration(s['noise_file']),
            exposure_scales_light=bool(s['exposure_scales_light']))

    def _make_camera_backend(self, backend: str, s: dict) -> CameraBackend:
        if s['trigger_source'] not in TRIGGER_SOURCES:
            raise ValueError(f'trigger_source {s["trigger_source"]!r}: use one of '
                             f'{", ".join(TRIGGER_SOURCES)}')
        common = dict(serial_number=s['serial_number'], pixel_format=s['pixel_format'],
                      features=split_features(s['camera_features']),
                      trigger_source=s['trigger_source'], exposure_us=float(s['exposure_us']),
                      gain_db=float(s['gain_db']), frame_timeout_s=float(s['frame_timeout_s']),
                      reopen_period_s=float(s['reopen_period_s']))
        if backend == 'basler':
            from .basler_backend import BaslerBackend
            return BaslerBackend(self._publish_frame, self._on_lost,
                                 transport_layer=s['transport_layer'], **common)
        from .aravis_backend import AravisBackend
        return AravisBackend(self._publish_frame, self._on_lost, **common)

    def _start_backend(self, s: dict) -> None:
        try:
            self.backend = self._make_backend(s)
        except (ValueError, OSError) as exc:
            self.backend = None
            self.error = f'camera not ready: {exc}'
            self.get_logger().error(self.error)
            return
        self.error = ''
        if self.real_camera:
            opened = self.backend.wait_open(10.0)
            text = f'{self.p("backend")} camera: {self.backend.status().message}'
            if opened:
                self.get_logger().info(text)
            else:
                self.get_logger().error(text)
            return
        cam = self.backend.camera
        self.get_logger().info(
            f'sim camera on {s["capture_dir"]}: {len(cam.modelset)} samples, '
            f'{cam.image_shape[1]}x{cam.image_shape[0]} px, {cam.bit_depth}-bit, noise {s["noise"]}'
            f'{" calibrated by " + s["noise_file"] if str(s["noise_file"]).strip() else ""}; '
            f'sample {cam.sample_name} on the stage')

    def _load_calibration(self, url: str) -> None:
        """Load camera_info_url; raises ValueError/OSError (the old calibration stays)."""
        self.calibration = load_calibration(url)
        self.calibration_error = ''

    def _on_set_parameters(self, params) -> SetParametersResult:
        refusal = other_backend_refusal([p.name for p in params], self.p('backend'))
        if refusal:
            return SetParametersResult(successful=False, reason=refusal)
        if any(p.name == 'camera_info_url' for p in params):
            url = next(p.value for p in params if p.name == 'camera_info_url')
            try:
                self._load_calibration(url)
            except (ValueError, OSError) as exc:
                return SetParametersResult(successful=False, reason=f'camera_info_url: {exc}')
        if self.real_camera:
            return self._set_camera_parameters(params)
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
            cam.exposure_scales_light = bool(s['exposure_scales_light'])
            if 'seed' in changes:
                cam.rng = np.random.default_rng(None if int(s['seed']) < 0 else int(s['seed']))
        except (ValueError, OSError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if 'sample' in changes:
            self.get_logger().info(f'sample {cam.sample_name} on the stage')
        return SetParametersResult(successful=True)

    def _set_camera_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params if p.name in CAMERA_SETTINGS + LIVE_CAMERA_SETTINGS}
        if not changes:
            return SetParametersResult(successful=True)
        s = self._settings(changes)
        if self.backend is not None and not set(changes) & set(CAMERA_SETTINGS):
            self.backend.exposure_us = float(s['exposure_us'])
            self.backend.gain_db = float(s['gain_db'])
            return SetParametersResult(successful=True)
        # a real camera cannot be opened twice: close it, then open with the new settings
        # (a setting the node refuses leaves the old camera running)
        try:
            if s['trigger_source'] not in TRIGGER_SOURCES or s['pixel_format'] not in PIXEL_FORMATS:
                raise ValueError(f'trigger_source must be one of {", ".join(TRIGGER_SOURCES)} and '
                                 f'pixel_format one of {", ".join(PIXEL_FORMATS)}')
            parse_features(split_features(s['camera_features']))
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if self.backend is not None:
            self.backend.close()
        self._start_backend(s)
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ frames
    def _on_illumination(self, msg: IlluminationState) -> None:
        trigger = trigger_from_message(msg)
        if self.backend is None:
            self.dropped += 1
            self.get_logger().warning(f'trigger {msg.sequence} not imaged: {self.error}',
                                      throttle_duration_sec=5.0)
            self._publish_lost(trigger, self.error)
            return
        reason = hand_trigger(self.backend, trigger)
        if reason:
            self._on_lost(LostFrame(trigger, reason))

    def _publish_frame(self, frame: Frame) -> None:
        image = image_message(frame, self.p('frame_id'))
        height, width = frame.image.shape
        calibration = self.calibration
        if calibration is not None:
            try:
                calibration = calibration.for_image(width, height)
            except ValueError as exc:
                if self.calibration_error != str(exc):
                    self.get_logger().error(f'{exc}; publishing an uncalibrated camera_info')
                self.calibration_error, calibration = str(exc), None
        info = camera_info_message(image.header, calibration or Calibration.uncalibrated(width, height))
        self._image_readers.wait()
        self._image_pub.publish(image)
        self._info_pub.publish(info)
        self.published += 1

    def _on_lost(self, lost: LostFrame) -> None:
        """A trigger without its frame (called from the backend's grab thread): no image is
        published for it; the reason goes to the log and, at once, to /diagnostics."""
        self.dropped += 1
        self.error = f'trigger {lost.trigger.sequence} not imaged: {lost.reason}'
        self.get_logger().error(self.error)
        self._publish_lost(lost.trigger, lost.reason)
        self.diagnostics.publish()

    def _publish_lost(self, trigger: Trigger, reason: str) -> None:
        """Tell whoever waits for this trigger's frame that it will not come, and why."""
        msg = FrameLost(sequence=int(trigger.sequence), reason=str(reason))
        msg.header.stamp = ns_to_stamp(trigger.stamp_ns)
        msg.header.frame_id = self.p('frame_id')
        self._lost_readers.wait()
        self._lost_pub.publish(msg)

    # ------------------------------------------------------------------ health
    def _camera_status(self) -> Report:
        values = {'backend': self.p('backend'), 'images_published': self.published,
                  'triggers_dropped': self.dropped, 'last_error': self.error,
                  'camera_info': (self.calibration.source if self.calibration else 'uncalibrated')}
        if not self.real_camera:
            values['capture_dir'] = self.p('capture_dir')
        if self.calibration_error:
            values['camera_info_error'] = self.calibration_error
        hardware_id = str(self.p('backend'))
        if self.backend is None:
            return Report(ERROR, self.error, values, hardware_id)
        health = self.backend.status()
        values.update(health.values)
        if health.ok and not self.error:
            return Report(OK, health.message, values, hardware_id)
        if not health.ok:
            return Report(ERROR, health.message, values, hardware_id)
        return Report(WARN, self.error, values, hardware_id)

    def destroy_node(self):
        if self.backend is not None:
            self.backend.close()
        return super().destroy_node()


def main(argv: list[str] | None = None) -> int:
    init_node(sys.argv if argv is None else argv)
    return spin_until_stopped(CameraNode())


if __name__ == '__main__':
    sys.exit(main())
