"""Acceptance on pylon's emulated camera: the driver (Python firmware simulator)
and the camera node with backend basler run as processes; pattern sequences fired through
ApplyPatterns give one mono16 image per trigger, equal to the served file, stamped with its
trigger, each with its camera_info; a failed buffer and a trigger without a frame give their
documented errors, a notice on camera/frame_lost in place of the image and no mis-paired
image, and the camera goes on without a restart.
"""
import numpy as np
import pytest
import yaml

from helpers.emulated_cameras import (EMULATED_SERIALS, PYLON_TIMEOUT, camera_graph, emulator_features,
                              write_served_images)
from lightstage_graph.frames import image_from_buffer
from lightstage_graph.stamps import stamp_to_ns
from helpers.suite import write_params

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('private_network'), PYLON_TIMEOUT]

K = [1210.5, 0.0, 31.5, 0.0, 1208.25, 23.5, 0.0, 0.0, 1.0]
D = [-0.12, 0.05, 0.001, -0.002, 0.0]
P = [1190.0, 0.0, 31.0, 0.0, 0.0, 1188.0, 23.0, 0.0, 0.0, 0.0, 1.0, 0.0]


def write_calibration(path):
    """camera_calibration's YAML for a 64 x 48 camera."""
    path.write_text(yaml.safe_dump({
        'image_width': 64, 'image_height': 48, 'camera_name': 'stage_cam',
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': K},
        'distortion_model': 'plumb_bob',
        'distortion_coefficients': {'rows': 1, 'cols': 5, 'data': D},
        'rectification_matrix': {'rows': 3, 'cols': 3, 'data': [1., 0, 0, 0, 1, 0, 0, 0, 1]},
        'projection_matrix': {'rows': 3, 'cols': 4, 'data': P}}))
    return path


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    root = tmp_path_factory.mktemp('basler_rig')
    rng = np.random.default_rng(1414)
    images = write_served_images(root / 'served', [rng.integers(0, 65536, (48, 64), dtype=np.uint16)
                                                   for _ in range(4)])
    calibration = write_calibration(root / 'stage_cam.yaml')
    features = '; '.join(emulator_features(root / 'served'))
    params = write_params(root / 'params.yaml', {'camera': {
        'backend': 'basler', 'transport_layer': 'BaslerCamEmu', 'serial_number': EMULATED_SERIALS[0],
        'trigger_source': 'Software', 'pixel_format': 'Mono16', 'frame_id': 'stage_cam',
        'camera_info_url': f'file://{calibration}', 'camera_features': features,
        'frame_timeout_s': 0.5, 'diagnostics_period_s': 0.2}})
    with camera_graph(params) as client:
        yield client, images, features


def received(client, stamps):
    by_stamp = {stamp_to_ns(m.header.stamp): m for m in client.images}
    return [by_stamp.get(s) for s in stamps]


def test_one_exact_mono16_image_per_trigger_with_its_camera_info(rig):
    client, images, _ = rig
    client.images.clear(), client.infos.clear()
    stamps, sequences = client.fire(6)
    client.spin_until(lambda: len(client.images) >= 6 and len(client.infos) >= 6, 30.0, 'six images')
    client.spin_for(0.3)
    assert len(client.images) == len(client.infos) == 6   # one per trigger, none extra
    decoded = []
    for i, (stamp, msg) in enumerate(zip(stamps, received(client, stamps))):
        assert msg is not None, f'no image stamped with trigger {sequences[i]}'
        assert (msg.encoding, msg.height, msg.width, msg.header.frame_id) == ('mono16', 48, 64, 'stage_cam')
        decoded.append(image_from_buffer(msg.data, msg.height, msg.width, msg.step, msg.encoding,
                                         msg.is_bigendian))
    # the served files in order, cycling, from wherever the set-up's trigger left the emulator
    first = next(k for k, served in enumerate(images) if np.array_equal(decoded[0], served))
    for i, image in enumerate(decoded):
        np.testing.assert_array_equal(image, images[(first + i) % len(images)])
    for image, info in zip(client.images, client.infos):
        assert info.header == image.header
        assert (info.width, info.height, info.distortion_model) == (64, 48, 'plumb_bob')
        np.testing.assert_allclose(info.k, K)
        np.testing.assert_allclose(info.d, D)
        np.testing.assert_allclose(info.p, P)
    client.diagnostics.clear()

    def camera_statuses():
        return [st for msg in client.diagnostics for st in msg.status if st.name.startswith('camera')]
    client.spin_until(camera_statuses, 10.0, "the camera's /diagnostics")
    status = camera_statuses()[-1]
    values = {kv.key: kv.value for kv in status.values}
    assert values['bit_depth'] == '16' and values['frames_lost'] == '0' and values['grab_timeouts'] == '0'
    assert float(values['frame_rate_hz']) > 0 and values['camera_info'].endswith('stage_cam.yaml')


def test_a_failed_buffer_and_a_trigger_without_frame_give_their_errors_and_no_mispaired_image(rig):
    client, images, features = rig
    # the camera reopens with these features: its first buffer fails
    results = client.set_parameters('camera', camera_features=features + '; ForceFailedBufferCount=1; '
                                                                         'ForceFailedBuffer')
    assert all(r.successful for r in results), results
    client.wait_camera_ready()
    client.images.clear(), client.diagnostics.clear(), client.lost.clear()
    stamps, sequences = client.fire(3)
    client.spin_until(lambda: len(client.images) >= 2 and client.lost, 30.0, 'two images and a notice')
    client.spin_for(0.5)
    first, second, third = received(client, stamps)
    assert first is None and len(client.images) == 2
    assert any(f'trigger {sequences[0]} not imaged: failed buffer: The buffer was incompletely grabbed.'
               in e for e in client.camera_errors()), client.camera_errors()
    # in place of the image: the notice on camera/frame_lost, stamped as the image would have been
    (lost,) = client.lost
    assert (stamp_to_ns(lost.header.stamp), lost.sequence) == (stamps[0], sequences[0])
    assert lost.reason.startswith('failed buffer: The buffer was incompletely grabbed.'), lost.reason
    # the failed buffer took the first served image: triggers 2 and 3 have the 2nd and 3rd
    for msg, expected in ((second, images[1]), (third, images[2])):
        image = image_from_buffer(msg.data, msg.height, msg.width, msg.step, msg.encoding, msg.is_bigendian)
        np.testing.assert_array_equal(image, expected)

    # Line1 without a wire: the triggers reach no camera; each is a grab timeout, no image
    assert all(r.successful for r in client.set_parameters('camera', camera_features=features,
                                                           trigger_source='Line1'))
    client.wait_camera_ready()
    client.images.clear(), client.diagnostics.clear(), client.lost.clear()
    stamps, sequences = client.fire(2)
    client.spin_until(lambda: any(f'trigger {sequences[1]} not imaged' in e for e in client.camera_errors())
                      and len(client.lost) == 2, 30.0, 'the second trigger to be reported lost')
    assert not client.images
    assert [(stamp_to_ns(m.header.stamp), m.sequence) for m in client.lost] == list(zip(stamps, sequences))
    reasons = [m.reason for m in client.lost]
    assert 'grab timeout' in reasons[0], reasons
    assert f'trigger {sequences[0]} had no frame' in reasons[1], reasons   # the camera resyncs
    errors = client.camera_errors()
    assert any(f'trigger {sequences[0]} not imaged: no frame within' in e and 'grab timeout' in e
               for e in errors), errors

    # back to the software trigger: the camera goes on, same node, no restart
    assert all(r.successful for r in client.set_parameters('camera', trigger_source='Software'))
    client.wait_camera_ready()
    client.images.clear()
    stamps, _ = client.fire(2)
    client.spin_until(lambda: len(client.images) >= 2, 30.0, 'two images')
    assert all(m is not None for m in received(client, stamps))
