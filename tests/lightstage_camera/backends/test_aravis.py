"""The aravis backend against Aravis's GigE Vision fake camera on 127.0.0.1 (in this process,
opened by address: no discovery scan), in a private network namespace: software trigger,
Mono16; directly and through the graph (driver on the Python firmware simulator + camera
node with backend aravis).

The fake camera cannot serve files; its image is a known function of its frame id (at
exposure 10 ms and gain 0: ((x + y + frame_id) mod 255) * 256 + 255), so each image says
which of the camera's frames it is: the n-th trigger must get the n-th frame.
"""
import time

import numpy as np
import pytest
from lightstage_camera.aravis_backend import AravisBackend, FrameIdCounter
from lightstage_camera.camera_backend import Trigger
from lightstage_graph.frames import image_from_buffer
from lightstage_graph.stamps import stamp_to_ns

from helpers.emulated_cameras import camera_graph
from helpers.suite import write_params

ADDRESS, SERIAL = '127.0.0.1', 'FAKE-LS-0001'
SIZE = (48, 64)
FEATURES = [f'Width={SIZE[1]}', f'Height={SIZE[0]}']


def fake_image(frame_id: int) -> np.ndarray:
    y, x = np.mgrid[0:SIZE[0], 0:SIZE[1]]
    return (((x + y + frame_id) % 255) * 256 + 255).astype(np.uint16)


@pytest.fixture(scope='module')
def fake_camera(private_network):
    """One GigE Vision fake camera for the module (its UDP port 3956 is fixed)."""
    import gi
    gi.require_version('Aravis', '0.8')
    from gi.repository import Aravis
    camera = Aravis.GvFakeCamera.new(ADDRESS, SERIAL)
    assert camera.is_running()
    yield camera
    del camera


def test_gige_vision_frame_ids_are_unwrapped_into_a_count():
    count = FrameIdCounter()
    assert [count(i) for i in (65533, 65534, 65535, 1, 2, 5)] == [0, 1, 2, 3, 4, 7]


def test_one_frame_per_software_trigger_in_order_with_settings_read_back(fake_camera):
    frames, lost = [], []
    backend = AravisBackend(frames.append, lost.append, serial_number=ADDRESS, pixel_format='Mono16',
                            trigger_source='Software', exposure_us=10000.0, gain_db=0.0,
                            features=FEATURES, frame_timeout_s=2.0)
    try:
        assert backend.wait_open(10.0), backend.status().message
        assert backend.status().values['serial'] == SERIAL
        for seq in range(5):
            backend.trigger(Trigger(stamp_ns=10 + seq, sequence=seq, exposure_us=10000, gain_db=0.0,
                                    led_intensities=np.zeros(32, np.float32)))
        backend.trigger(Trigger(stamp_ns=99, sequence=5, exposure_us=20_000_000, gain_db=0.0,
                                led_intensities=np.zeros(32, np.float32)))
        end = time.monotonic() + 30
        while len(frames) + len(lost) < 6 and time.monotonic() < end:
            time.sleep(0.01)
        assert [f.trigger.sequence for f in frames] == [0, 1, 2, 3, 4]
        ids = [f.info['frame_id'] for f in frames]
        assert [f.info['block_id'] for f in frames] == list(range(5))
        for f in frames:
            assert f.bit_depth == 16 and f.info['exposure_us'] == 10000.0 and f.info['gain_db'] == 0.0
            np.testing.assert_array_equal(f.image, fake_image(f.info['frame_id']))
        assert all(b - a in (1, 1 - 65535) for a, b in zip(ids, ids[1:]))
        (refused,) = lost
        assert refused.trigger.sequence == 5 and 'outside the camera\'s range' in refused.reason
    finally:
        backend.close()


def test_a_missing_camera_is_reported(fake_camera):
    frames, lost = [], []
    backend = AravisBackend(frames.append, lost.append, serial_number='127.0.0.2',
                            pixel_format='Mono16', trigger_source='Software', reopen_period_s=5.0)
    try:
        assert not backend.wait_open(20.0)
        assert 'no GenICam camera 127.0.0.2' in backend.status().message
    finally:
        backend.close()


@pytest.mark.ros
def test_a_pattern_sequence_through_the_driver_gives_one_image_per_trigger(fake_camera, tmp_path):
    params = write_params(tmp_path / 'params.yaml', {'camera': {
        'backend': 'aravis', 'serial_number': ADDRESS, 'trigger_source': 'Software',
        'pixel_format': 'Mono16', 'exposure_us': 10000.0, 'gain_db': 0.0,
        'camera_features': '; '.join(FEATURES), 'frame_timeout_s': 2.0, 'diagnostics_period_s': 0.2}})
    with camera_graph(params) as client:
        stamps, _ = client.fire(5, exposure_us=10000)
        client.spin_until(lambda: len(client.images) >= 5 and len(client.infos) >= 5, 30.0,
                          lambda: f'five images; camera errors: {client.camera_errors()[-3:]}')
        client.spin_for(0.3)
    images, infos = client.images, client.infos
    assert len(images) == len(infos) == 5
    assert [stamp_to_ns(m.header.stamp) for m in images] == stamps
    decoded = [image_from_buffer(m.data, m.height, m.width, m.step, m.encoding, m.is_bigendian)
               for m in images]
    first = next(i for i in range(255) if np.array_equal(decoded[0], fake_image(i)))
    for k, image in enumerate(decoded):   # consecutive frames of the camera, in trigger order
        np.testing.assert_array_equal(image, fake_image(first + k))
    for image, info in zip(images, infos):
        assert info.header == image.header and (info.width, info.height) == (SIZE[1], SIZE[0])
