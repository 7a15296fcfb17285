"""The basler backend (pypylon) against pylon's emulated camera, without ROS.

Only the emulation transport layer is enumerated (transport_layer BaslerCamEmu), in a
private network namespace (`private_network`).
"""
import time

import numpy as np
import pytest

from helpers.emulated_cameras import EMULATED_SERIALS, PYLON_TIMEOUT, emulator_features
from lightstage_camera.basler_backend import BaslerBackend
from lightstage_camera.camera_backend import CameraError, Trigger

pytestmark = [pytest.mark.usefixtures('private_network'), PYLON_TIMEOUT]


class Collected:
    def __init__(self):
        self.frames, self.lost = [], []

    def wait(self, n, limit_s=20.0):
        end = time.monotonic() + limit_s
        while len(self.frames) + len(self.lost) < n and time.monotonic() < end:
            time.sleep(0.005)
        return len(self.frames) + len(self.lost)


def make(collected, **kwargs):
    settings = dict(transport_layer='BaslerCamEmu', pixel_format='Mono16', trigger_source='Software',
                    exposure_us=1000.0, gain_db=0.0, frame_timeout_s=1.0, reopen_period_s=0.2)
    settings.update(kwargs)
    backend = BaslerBackend(collected.frames.append, collected.lost.append, **settings)
    return backend


@pytest.fixture
def backends():
    made = []
    yield made
    for b in made:
        b.close()


def trigger(seq, exposure_us=2000, gain_db=float('nan')):
    return Trigger(stamp_ns=1_700_000_000_000_000_000 + seq, sequence=seq,
                   led_intensities=np.zeros(32, np.float32), exposure_us=exposure_us, gain_db=gain_db)


def test_served_images_come_back_exactly_one_per_trigger_with_settings_read_back(backends, served_images):
    folder, images = served_images
    got = Collected()
    backends.append(b := make(got, features=emulator_features(folder), serial_number=EMULATED_SERIALS[1]))
    assert b.wait_open(10.0), b.status().message
    settings = [(2000, 0.0), (5000, 17.5), (22500, float('nan')), (40, 6.0), (1000, 48.0), (30000, 1.25)]
    for seq, (exposure, gain) in enumerate(settings):
        b.trigger(trigger(seq, exposure, gain))
    assert got.wait(len(settings)) == len(settings)
    assert not got.lost
    assert [f.trigger.sequence for f in got.frames] == list(range(len(settings)))
    for i, (f, (exposure, gain)) in enumerate(zip(got.frames, settings)):
        assert f.bit_depth == 16 and f.image.dtype == np.uint16
        np.testing.assert_array_equal(f.image, images[i % len(images)])  # served in order, cycling
        assert f.info['exposure_us'] == pytest.approx(exposure, abs=1.0)
        assert f.info['gain_db'] == pytest.approx(0.0 if np.isnan(gain) else gain, abs=0.01)
        assert f.info['block_id'] == i
    status = b.status()
    assert status.ok and status.values['serial'] == EMULATED_SERIALS[1]
    assert status.values['bit_depth'] == 16 and status.values['frames_lost'] == 0


@pytest.mark.parametrize('pixel_format, bits', [('Mono8', 8), ('Mono10', 10), ('Mono12', 12)])
def test_narrower_pixel_formats_are_published_msb_aligned(backends, served_images, pixel_format, bits):
    folder, images = served_images
    got = Collected()
    backends.append(b := make(got, features=emulator_features(folder), pixel_format=pixel_format))
    assert b.wait_open(10.0), b.status().message
    b.trigger(trigger(0))
    assert got.wait(1) == 1 and got.frames, got.lost
    frame = got.frames[0]
    assert frame.bit_depth == bits == b.status().values['bit_depth']
    # the camera keeps the top `bits` bits of the served 16-bit values; mono16 puts them back on top
    mask = np.uint16((0xFFFF << (16 - bits)) & 0xFFFF)
    np.testing.assert_array_equal(frame.image, images[0] & mask)


def test_settings_the_camera_cannot_meet_are_refused_and_the_camera_goes_on(backends, served_images):
    folder, images = served_images
    got = Collected()
    backends.append(b := make(got, features=emulator_features(folder)))
    assert b.wait_open(10.0)
    b.trigger(trigger(0, exposure_us=20_000_000))
    b.trigger(trigger(1, gain_db=60.0))
    b.trigger(trigger(2))
    assert got.wait(3) == 3
    assert [x.trigger.sequence for x in got.lost] == [0, 1]
    assert "exposure 2e+07 us is outside the camera's range 1..1e+07 us" in got.lost[0].reason
    assert "gain 60 dB is outside the camera's range 0..48" in got.lost[1].reason
    (frame,) = got.frames
    assert frame.trigger.sequence == 2
    np.testing.assert_array_equal(frame.image, images[0])   # the refused triggers took no frame


def test_a_failed_buffer_loses_its_trigger_and_the_next_frame_goes_to_the_next_trigger(backends, served_images):
    folder, images = served_images
    got = Collected()
    backends.append(b := make(got, features=[*emulator_features(folder), 'ForceFailedBufferCount=1']))
    assert b.wait_open(10.0)
    b.trigger(trigger(0))
    assert got.wait(1) == 1
    b._camera.ForceFailedBuffer.Execute()   # the emulator fails the next buffer
    b.trigger(trigger(1))
    b.trigger(trigger(2))
    assert got.wait(3) == 3
    assert [f.trigger.sequence for f in got.frames] == [0, 2]
    (lost,) = got.lost
    assert lost.trigger.sequence == 1
    assert lost.reason.startswith('failed buffer: The buffer was incompletely grabbed.')
    # the failed buffer took the second image; trigger 2 has the third, not the second
    np.testing.assert_array_equal(got.frames[1].image, images[2])
    assert b.status().values['frames_lost'] == 1


def test_a_hardware_trigger_that_never_came_is_a_grab_timeout_not_a_frame(backends, served_images):
    folder, _ = served_images
    got = Collected()
    # Line1 as on the stage: the emulator has no wire, so no frame can come
    backends.append(b := make(got, features=emulator_features(folder), trigger_source='Line1',
                              frame_timeout_s=0.2))
    assert b.wait_open(10.0)
    assert b.status().values['exposure_mode'] == 'TriggerWidth'
    b.trigger(trigger(0, gain_db=0.0))
    assert got.wait(1) == 1
    (lost,) = got.lost
    assert not got.frames and 'no frame within 0.202 s of the trigger (grab timeout' in lost.reason
    status = b.status()
    assert status.values['grab_timeouts'] == 1 and status.values['frames_lost'] == 1


def test_a_missing_camera_is_reported_and_every_trigger_lost_with_the_reason(backends):
    got = Collected()
    backends.append(b := make(got, serial_number='4711-0000'))
    assert not b.wait_open(10.0)
    status = b.status()
    assert not status.ok
    assert ('no Basler camera with serial number 4711-0000 on transport layer BaslerCamEmu; found '
            '0815-0000, 0815-0001' in status.message)
    b.trigger(trigger(0))
    assert got.wait(1) == 1
    assert got.lost[0].reason.startswith('camera not open: no Basler camera with serial number 4711')


class UnpluggableBackend(BaslerBackend):
    """The emulator cannot be unplugged: this one reports the removal pylon would."""

    def __init__(self, *args, **kwargs):
        import threading
        self.unplug = threading.Event()
        super().__init__(*args, **kwargs)

    def _device_retrieve(self, timeout_s):
        if self.unplug.is_set():
            self.unplug.clear()
            raise CameraError('the camera was removed (unplugged, or its power or cable failed)')
        return super()._device_retrieve(timeout_s)


def test_after_a_removal_the_waiting_triggers_are_lost_and_the_camera_is_reopened(backends, served_images):
    folder, images = served_images
    got = Collected()
    backends.append(b := UnpluggableBackend(
        got.frames.append, got.lost.append, transport_layer='BaslerCamEmu', pixel_format='Mono16',
        trigger_source='Line1', frame_timeout_s=30.0, reopen_period_s=0.2,
        features=emulator_features(folder)))
    assert b.wait_open(10.0)
    b.trigger(trigger(0, gain_db=b.gain_db))   # waits: Line1 never pulses
    while b.pairing.waiting == 0:
        time.sleep(0.005)
    b.unplug.set()
    assert got.wait(1) == 1
    assert got.lost[0].reason == ('camera fault: the camera was removed (unplugged, or its power or '
                                  'cable failed)')
    end = time.monotonic() + 20
    while not b.status().ok and time.monotonic() < end:
        time.sleep(0.01)
    assert b.status().ok and b.reopens == 1 and 'removed' in b.status().values['last_fault']


def test_hardware_triggered_frames_pair_with_triggers_announced_after_them(backends, served_images):
    """Line1 as on the stage; TriggerSoftware stands in for the wire (the emulator fires on it
    whatever the source). Frames come before the driver's announcements; a frame taken at
    another gain than its trigger asked for is not delivered as that trigger's."""
    folder, images = served_images
    got = Collected()
    backends.append(b := make(got, features=emulator_features(folder), trigger_source='Line1',
                              gain_db=6.0))
    assert b.wait_open(10.0)

    def pulse():
        assert b._camera.WaitForFrameTriggerReady(2000, 0)   # TimeoutHandling_Return
        b._camera.TriggerSoftware.Execute()

    for _ in range(3):
        pulse()
    end = time.monotonic() + 10
    while b.pairing.unclaimed == 0 and len(b.pairing._early) < 3 and time.monotonic() < end:
        time.sleep(0.005)
    for seq in range(3):   # NaN: the node's gain (6 dB), which the camera has
        b.trigger(trigger(seq, exposure_us=2000, gain_db=float('nan')))
    assert got.wait(3) == 3 and not got.lost, (got.lost, b.pairing.unclaimed, len(got.frames))
    for i, f in enumerate(got.frames):
        assert f.trigger.sequence == i
        np.testing.assert_array_equal(f.image, images[i])
        assert f.info['gain_db'] == pytest.approx(6.0, abs=0.01)
    pulse()
    b.trigger(trigger(3, gain_db=12.0))   # the pulse was taken at 6 dB
    assert got.wait(4) == 4
    (lost,) = got.lost
    assert lost.trigger.sequence == 3
    assert lost.reason.startswith('the frame was taken at 6.00 dB, the trigger asked for 12.00 dB')
    assert b.actual_gain_db == pytest.approx(12.0, abs=0.01)   # set for the next triggers


def test_no_camera_at_all_names_the_serial_number_asked_for(monkeypatch):
    """`serial_number: NOT-A-SERIAL` with no camera said `no Basler camera found`."""
    from types import SimpleNamespace
    stub = SimpleNamespace(serial_number='NOT-A-SERIAL', transport_layer='',
                           _devices=lambda pylon: (None, []))
    with pytest.raises(CameraError, match="no Basler camera found \\(looking for serial number "
                                          "'NOT-A-SERIAL'\\): is it plugged in"):
        BaslerBackend._device_open(stub)
