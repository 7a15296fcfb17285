"""GenICam cameras (GigE Vision, USB3 Vision: FLIR, Allied Vision, Hikrobot, ...) through
Aravis (Debian ``gir1.2-aravis-0.8``) and PyGObject.

Behaves as the Basler backend (`triggered_backend`): ``TriggerSelector=FrameStart``,
``TriggerMode=On``, ``TriggerSource``; ``PixelFormat`` Mono8/10/12/16 published as mono16
MSB-aligned; exposure [us] and gain per trigger, read back. `serial_number` is what
``arv_open_device`` takes: an IP address (opened directly, no discovery), a device id
(Vendor-Model-Serial) or a serial; empty opens the first camera found, which broadcasts a
discovery on every interface.

GigE Vision streams use a plain UDP socket with a fixed 8 MiB buffer (the packet socket
and Aravis's automatic buffer lost or cut frames on loopback). Frame ids of GigE Vision 1
are 16 bits, 1..65535 (0 is skipped on wrap-around); they are unwrapped into a count for
the gap detection. Aravis has no "wait for frame-trigger ready": for a software trigger
the backend waits until the previous trigger's frame has arrived. Gain: the camera's
``Gain`` feature in dB where it has one (Aravis's camera API falls back to ``GainRaw``, in
the camera's own units, on older cameras: reported as such). No rclpy here.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Sequence

import numpy as np

from .camera_backend import CameraError, Frame, LostFrame, to_mono16
from .trigger_pairing import GrabbedFrame
from .triggered_backend import TriggeredBackend, check_pixel_format, parse_features

STREAM_BUFFERS = 16
SOCKET_BUFFER_BYTES = 8 * 1024 * 1024
GV_FRAME_IDS = 65535   # GigE Vision 1 block ids run 1..65535


def _aravis():
    try:
        import gi
        gi.require_version('Aravis', '0.8')
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise CameraError(f'Aravis is not available ({exc}): install the Debian packages '
                          'libaravis-0.8-0 gir1.2-aravis-0.8 and PyGObject (`make camera` '
                          'does both)') from exc
    return Aravis


class FrameIdCounter:
    """GigE Vision 16-bit frame ids (1..65535, 0 skipped) -> a count that keeps increasing."""

    def __init__(self, period: int = GV_FRAME_IDS):
        self.period = period
        self.last_raw: int | None = None
        self.count = 0

    def __call__(self, raw: int) -> int:
        if self.last_raw is not None:
            step = raw - self.last_raw
            if step < 0 and self.last_raw - raw > self.period // 2:   # wrapped: 0 is skipped
                step += self.period
            self.count += step
        self.last_raw = raw
        return self.count


class AravisBackend(TriggeredBackend):
    """`TriggeredBackend` on any GenICam camera through Aravis."""

    name = 'aravis'

    def __init__(self, deliver: Callable[[Frame], None], lost: Callable[[LostFrame], None] | None = None,
                 *, serial_number: str = '', pixel_format: str = 'Mono10', features: Sequence[str] = (),
                 **kwargs):
        self.bit_depth = check_pixel_format(pixel_format)
        self.serial_number = str(serial_number).strip()
        self.pixel_format = pixel_format
        self.features = parse_features(features)
        self._camera = self._stream = None
        self._removed = threading.Event()
        self._frame_ids = FrameIdCounter()
        super().__init__(deliver, lost, **kwargs)

    def _device_open(self) -> dict:
        Aravis = _aravis()
        self._removed.clear()
        self._frame_ids = FrameIdCounter()
        try:
            camera = Aravis.Camera.new(self.serial_number or None)
        except Exception as exc:  # GLib.Error: the camera is not there
            raise CameraError(f'no GenICam camera {self.serial_number or "(first found)"}: {exc}; '
                              'is it plugged in, powered and (GigE) on this subnet?') from exc
        self._camera = camera
        try:
            device = camera.get_device()
            device.connect('control-lost', lambda *_: self._removed.set())
            available = camera.dup_available_pixel_formats_as_strings()
            if self.pixel_format not in available:
                raise CameraError(f'PixelFormat {self.pixel_format} is not offered by this camera; '
                                  f'it offers {", ".join(available)}')
            camera.set_pixel_format_from_string(self.pixel_format)
            camera.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
            if camera.is_exposure_auto_available():
                camera.set_exposure_time_auto(Aravis.Auto.OFF)
            if camera.is_gain_auto_available():
                camera.set_gain_auto(Aravis.Auto.OFF)
            sources = camera.dup_available_trigger_sources()
            if self.trigger_source not in sources:
                raise CameraError(f'TriggerSource cannot be {self.trigger_source} on this camera; '
                                  f'it offers {", ".join(sources)}')
            camera.set_trigger(self.trigger_source)   # FrameStart, TriggerMode On, the source
            for name, value in self.features:
                if value is None:
                    device.execute_command(name)
                else:
                    device.set_features_from_string(f'{name}={value}')
            if camera.is_gv_device():
                camera.gv_set_stream_options(Aravis.GvStreamOption.PACKET_SOCKET_DISABLED)
            stream = camera.create_stream(None, None)
            if camera.is_gv_device():
                stream.set_property('socket-buffer', Aravis.GvStreamSocketBuffer.FIXED)
                stream.set_property('socket-buffer-size', SOCKET_BUFFER_BYTES)
            payload = camera.get_payload()
            for _ in range(STREAM_BUFFERS):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            self._stream = stream
            camera.start_acquisition()
            gain_in_db = device.is_feature_available('Gain')
            return {'model': f'{camera.get_vendor_name()} {camera.get_model_name()}',
                    'serial': device.get_string_feature_value('DeviceSerialNumber')
                    if device.is_feature_available('DeviceSerialNumber') else camera.get_device_id(),
                    'pixel_format': self.pixel_format, 'bit_depth': self.bit_depth,
                    'gain_unit': 'dB' if gain_in_db else 'GainRaw (camera units)',
                    'exposure_mode': 'Timed'}
        except CameraError:
            self._device_close()
            raise
        except Exception as exc:  # GLib.Error from a feature the camera refused
            self._device_close()
            raise CameraError(f'the camera refused its configuration: {exc}') from exc

    def _device_close(self) -> None:
        camera, self._camera, self._stream = self._camera, None, None
        if camera is not None:
            try:
                camera.stop_acquisition()
            except Exception:  # noqa: BLE001 - a camera that is gone cannot stop; it is closed
                pass

    @staticmethod
    def _check(value: float, bounds, what: str, unit: str) -> None:
        lo, hi = bounds
        if not lo <= value <= hi:
            raise ValueError(f'{what} {value:g} {unit} is outside the camera\'s range {lo:g}..{hi:g} {unit}')

    def _device_apply(self, exposure_us: float, gain_db: float) -> tuple[float, float]:
        camera = self._camera
        self._check(gain_db, camera.get_gain_bounds(), 'gain', 'dB')
        self._check(exposure_us, camera.get_exposure_time_bounds(), 'exposure', 'us')
        if abs(camera.get_gain() - gain_db) > 1e-9:
            camera.set_gain(float(gain_db))
        if abs(camera.get_exposure_time() - exposure_us) > 1e-9:
            camera.set_exposure_time(float(exposure_us))
        return float(camera.get_exposure_time()), float(camera.get_gain())

    def _device_wait_ready(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while self.pairing.waiting and time.monotonic() < end:
            time.sleep(0.0005)
        return not self.pairing.waiting

    def _device_fire(self) -> None:
        self._camera.software_trigger()

    def _device_retrieve(self, timeout_s: float) -> GrabbedFrame | None:
        if self._removed.is_set():
            raise CameraError('the camera was removed (control lost: unplugged, or its power '
                              'or network failed)')
        Aravis = _aravis()
        buffer = self._stream.timeout_pop_buffer(max(1, int(timeout_s * 1e6)))
        if buffer is None:
            return None
        try:
            raw_id = int(buffer.get_frame_id())
            block = self._frame_ids(raw_id)
            status = buffer.get_status()
            if status != Aravis.BufferStatus.SUCCESS:
                return GrabbedFrame(block, None, self.bit_depth,
                                    error=f'buffer status {status.value_nick}')
            height, width = buffer.get_image_height(), buffer.get_image_width()
            dtype = np.uint8 if self.bit_depth == 8 else np.dtype('<u2')
            data = np.frombuffer(buffer.get_image_data(), dtype=dtype)
            image = to_mono16(data[:height * width].reshape(height, width), self.bit_depth)
            return GrabbedFrame(block, image, self.bit_depth, info={'frame_id': raw_id})
        finally:
            self._stream.push_buffer(buffer)

    def _device_temperature(self) -> float | None:
        try:
            device = self._camera.get_device()
            if device.is_feature_available('DeviceTemperature'):
                return float(device.get_float_feature_value('DeviceTemperature'))
        except Exception:  # noqa: BLE001 - a temperature that cannot be read is not reported
            pass
        return None
