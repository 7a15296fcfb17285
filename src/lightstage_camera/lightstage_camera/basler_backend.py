"""Basler cameras through pypylon (pylon's Python binding), e.g. the paper's acA1920-150um.

Opens the camera with `serial_number` (empty: the first camera found), sets
``TriggerSelector=FrameStart``, ``TriggerMode=On``, ``TriggerSource`` (``Line1``: the
stage's trigger pin; ``Software``), ``PixelFormat`` Mono8/10/12/16 (published as ``mono16``
MSB-aligned, with the bit depth stated), exposure [us] and gain [dB] per trigger, read back.
With a line source the camera exposes for the trigger pulse (``ExposureMode=TriggerWidth``,
where the camera has it): the firmware holds the pin high for exactly the exposure.

`transport_layer` restricts the device search to one pylon transport layer: the tests and
the benchmark use ``BaslerCamEmu`` (pylon's camera emulation, ``PYLON_CAMEMU=N`` cameras),
so that no GigE discovery broadcast is sent; empty searches every layer (a real rig).
`features` are extra GenICam settings applied in order after the rest: ``Name=Value``, or a
command ``Name`` to execute (e.g. the emulator's ``ImageFilename=/path/to/images``,
``ImageFileMode=On``, ``TestImageSelector=Off``; a real camera's ``UserSetSelector=UserSet1``,
``UserSetLoad``, ``LineDebouncerTime=10``). No rclpy here.
"""
from __future__ import annotations

import os
from typing import Callable, Sequence

from .camera_backend import CameraError, Frame, LostFrame, to_mono16
from .triggered_backend import SOFTWARE, TriggeredBackend, check_pixel_format, parse_features
from .trigger_pairing import GrabbedFrame

EMULATION_TL = 'BaslerCamEmu'


def _pylon():
    try:
        from pypylon import genicam, pylon
    except ImportError as exc:
        raise CameraError(f'pypylon is not installed ({exc}); `pip install pypylon` '
                          '(`make camera` installs it: requirements-camera.txt)') from exc
    return pylon, genicam


class BaslerBackend(TriggeredBackend):
    """`TriggeredBackend` on a Basler camera (pypylon)."""

    name = 'basler'

    def __init__(self, deliver: Callable[[Frame], None], lost: Callable[[LostFrame], None] | None = None,
                 *, serial_number: str = '', pixel_format: str = 'Mono10', transport_layer: str = '',
                 features: Sequence[str] = (), **kwargs):
        self.bit_depth = check_pixel_format(pixel_format)
        self.serial_number = str(serial_number).strip()
        self.pixel_format = pixel_format
        self.transport_layer = str(transport_layer).strip()
        self.features = parse_features(features)
        self._camera = None
        self._exposure_node = self._gain_node = None
        self._by_pulse = False
        super().__init__(deliver, lost, **kwargs)

    # ------------------------------------------------------------------ open / close
    def _devices(self, pylon):
        factory = pylon.TlFactory.GetInstance()
        if not self.transport_layer:
            return factory, factory.EnumerateDevices()
        if self.transport_layer == EMULATION_TL:
            os.environ.setdefault('PYLON_CAMEMU', '1')  # read when the layer is first created
        layer = factory.CreateTl(self.transport_layer)
        if layer is None:
            raise CameraError(f'pylon has no transport layer {self.transport_layer!r} (e.g. '
                              f'{EMULATION_TL}, BaslerUsb, BaslerGigE; empty = all)')
        return layer, layer.EnumerateDevices()

    def _device_open(self) -> dict:
        pylon, genicam = _pylon()
        creator, devices = self._devices(pylon)
        serials = [d.GetSerialNumber() for d in devices]
        where = f' on transport layer {self.transport_layer}' if self.transport_layer else ''
        asked = f' (looking for serial number {self.serial_number!r})' if self.serial_number else ''
        if not devices:
            raise CameraError(f'no Basler camera found{where}{asked}: is it plugged in and powered '
                              '(USB3: a USB 3 port; GigE: same subnet, jumbo frames)?')
        if self.serial_number and self.serial_number not in serials:
            raise CameraError(f'no Basler camera with serial number {self.serial_number}{where}; '
                              f'found {", ".join(serials)} (set serial_number, or empty for the first)')
        info = devices[serials.index(self.serial_number) if self.serial_number else 0]
        camera = pylon.InstantCamera(creator.CreateDevice(info))
        try:
            camera.Open()
            self._camera = camera
            self._configure(genicam)
            camera.StartGrabbing(pylon.GrabStrategy_OneByOne)
        except genicam.GenericException as exc:
            self._device_close()
            raise CameraError(f'Basler camera {info.GetSerialNumber()} refused its configuration: '
                              f'{exc}') from exc
        return {'model': info.GetModelName(), 'serial': info.GetSerialNumber(),
                'pixel_format': self.pixel_format, 'bit_depth': self.bit_depth,
                'exposure_mode': 'TriggerWidth' if self._by_pulse else 'Timed'}

    def _node(self, name: str):
        from pypylon import genicam
        node = self._camera.GetNodeMap().GetNode(name)
        return node if node is not None and genicam.IsAvailable(node) else None

    def _set(self, name: str, value: str, required: bool = True) -> None:
        node = self._node(name)
        if node is None:
            if required:
                raise CameraError(f'the camera has no feature {name}')
            return
        symbolics = node.GetSymbolics() if hasattr(node, 'GetSymbolics') else None
        if symbolics is not None and value not in symbolics:
            raise CameraError(f'{name} cannot be {value!r} on this camera; it offers '
                              f'{", ".join(symbolics)}')
        node.FromString(str(value))

    def _execute(self, name: str) -> None:
        node = self._node(name)
        if node is None or not hasattr(node, 'Execute'):
            raise CameraError(f'the camera has no command {name}')
        node.Execute()

    def _configure(self, genicam) -> None:
        self._set('AcquisitionMode', 'Continuous', required=False)
        self._set('PixelFormat', self.pixel_format)
        self._set('ExposureAuto', 'Off', required=False)
        self._set('GainAuto', 'Off', required=False)
        self._set('TriggerSelector', 'FrameStart')
        self._set('TriggerMode', 'On')
        self._set('TriggerSource', self.trigger_source)
        if self.trigger_source != SOFTWARE:
            self._set('TriggerActivation', 'RisingEdge', required=False)  # the firmware pulses high
        mode = self._node('ExposureMode')
        self._by_pulse = (self.trigger_source != SOFTWARE and mode is not None
                          and 'TriggerWidth' in mode.GetSymbolics())
        if mode is not None:
            self._set('ExposureMode', 'TriggerWidth' if self._by_pulse else 'Timed')
        self._exposure_node = self._node('ExposureTime') or self._node('ExposureTimeAbs')
        self._gain_node = self._node('Gain') or self._node('GainAbs')
        if self._gain_node is None:
            raise CameraError('the camera has no Gain feature in dB (GainRaw-only cameras are '
                              'not supported)')
        for name, value in self.features:
            try:
                if value is None:
                    self._execute(name)
                else:
                    self._set(name, value)
            except genicam.GenericException as exc:
                raise CameraError(f'feature {name}={value} was refused: {exc}') from exc

    def _device_close(self) -> None:
        camera, self._camera = self._camera, None
        if camera is None:
            return
        try:
            if camera.IsGrabbing():
                camera.StopGrabbing()
            camera.Close()
        finally:
            camera.DestroyDevice()

    # ------------------------------------------------------------------ settings
    @staticmethod
    def _apply_one(node, value: float, what: str, unit: str) -> float:
        lo, hi = node.GetMin(), node.GetMax()
        if not lo <= value <= hi:
            raise ValueError(f'{what} {value:g} {unit} is outside the camera\'s range '
                             f'{lo:g}..{hi:g} {unit}')
        if abs(node.GetValue() - value) > 1e-9 * max(1.0, abs(value)):
            node.SetValue(float(value))
        return float(node.GetValue())

    def _device_apply(self, exposure_us: float, gain_db: float) -> tuple[float, float]:
        gain = self._apply_one(self._gain_node, gain_db, 'gain', 'dB')
        if self._by_pulse or self._exposure_node is None:
            return float(exposure_us), gain   # the pulse width is the exposure
        return self._apply_one(self._exposure_node, exposure_us, 'exposure', 'us'), gain

    def _device_exposure_by_pulse(self) -> bool:
        return self._by_pulse

    # ------------------------------------------------------------------ triggers and frames
    def _device_wait_ready(self, timeout_s: float) -> bool:
        from pypylon import pylon
        return bool(self._camera.WaitForFrameTriggerReady(max(1, int(timeout_s * 1000)),
                                                          pylon.TimeoutHandling_Return))

    def _device_fire(self) -> None:
        self._camera.ExecuteSoftwareTrigger()

    def _device_retrieve(self, timeout_s: float) -> GrabbedFrame | None:
        from pypylon import pylon
        camera = self._camera
        if camera.IsCameraDeviceRemoved():
            raise CameraError('the camera was removed (unplugged, or its power or cable failed)')
        result = camera.RetrieveResult(max(1, int(timeout_s * 1000)), pylon.TimeoutHandling_Return)
        if result is None or not result.IsValid():
            return None
        try:
            block = int(result.BlockID)
            if not result.GrabSucceeded():
                return GrabbedFrame(block, None, self.bit_depth,
                                    error=f'{result.GetErrorDescription()} (pylon error '
                                          f'0x{result.GetErrorCode():x})')
            image = to_mono16(result.Array, self.bit_depth)
            return GrabbedFrame(block, image, self.bit_depth)
        finally:
            result.Release()

    def _device_temperature(self) -> float | None:
        try:
            node = self._node('DeviceTemperature')
            return float(node.GetValue()) if node is not None else None
        except Exception:  # noqa: BLE001 - a temperature that cannot be read is not reported
            return None
