"""The whole method on pylon's emulated camera: driver (Python firmware simulator),
camera node with backend basler, acquisition and classifier nodes as processes; `lightstage
capture` writes a valid capture folder, `lightstage calibrate` runs to the end, and the
Classify service returns the label of the sample whose images the camera serves; a frame the
camera loses (a forced failed buffer) ends a classify or capture request with the camera's
reason, not with the request's own timeout.

The emulated camera serves files (its image-file feature); each step reopens it on a folder
of its own (camera_features), which restarts the files in sorted order.
"""
import json
import subprocess

import numpy as np
import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.emulated_cameras import (EMULATED_SERIALS, PYLON_TIMEOUT, emulator_features,
                              write_served_images)
from lightstage_physics.capture_format import load_capture
from lightstage_physics.noise import load_noise_file
from lightstage_camera.sim_camera import SimCamera, encode_mono16
from helpers.suite import GraphClient, fresh_domain_id, lightstage_command, start_nodes, write_params

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('private_network'), PYLON_TIMEOUT, pytest.mark.process]

SAMPLE = 'orange-real/s1/p02'


def cli(*args, domain_id: int):
    return subprocess.run(lightstage_command(*args, '--domain-id', str(domain_id)),
                          capture_output=True, text=True, timeout=300)


class Client(GraphClient):
    def __init__(self, domain_id):
        super().__init__(domain_id)
        from lightstage_interfaces.msg import IlluminationState
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        self.illumination = []
        self.node.create_subscription(IlluminationState, '/illumination', self.illumination.append,
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))

    def serve(self, folder, *more_features):
        """Reopen the emulated camera on the files of `folder` (and `more_features`)."""
        features = [*emulator_features(folder), *more_features]
        (ok,) = self.set_parameters('camera', camera_features='; '.join(features))
        assert ok.successful, ok.reason

    def classify(self):
        from lightstage_interfaces.srv import Classify
        return self.call(Classify, '/lightstage/classify',
                         Classify.Request(max_images=8, timeout_s=20.0), timeout_s=40.0)


@pytest.fixture(scope='module')
def graph(tmp_path_factory, stage_artifact_path):
    root = tmp_path_factory.mktemp('basler_e2e')
    rng = np.random.default_rng(5)
    write_served_images(root / 'first', [rng.integers(0, 1 << 16, (48, 64), dtype=np.uint16)
                                         for _ in range(2)])
    params = write_params(root / 'params.yaml', {
        'camera': {'backend': 'basler', 'transport_layer': 'BaslerCamEmu',
                   'serial_number': EMULATED_SERIALS[0], 'trigger_source': 'Software',
                   'pixel_format': 'Mono10', 'camera_features': '; '.join(emulator_features(root / 'first'))},
        'acquisition': {'exposure_us': 2000, 'gain_db': 15.0, 'frames_averaged': 2,
                        'camera_bit_depth': 10},
        'classifier': {'artifact_path': str(stage_artifact_path), 'timeout_s': 20.0,
                       'camera_bit_depth': 10},
    })
    domain_id = fresh_domain_id()
    client = Client(domain_id)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'acquisition', 'classifier'],
                        domain_id, params)
            yield client, root
    finally:
        client.close()


def test_capture_writes_a_valid_capture_folder(graph, tmp_path):
    client, root = graph
    rng = np.random.default_rng(6)
    # gray levels below the camera's maximum: the capture refuses clipped images
    served = [(rng.integers(0, 800, (48, 64)) << 6).astype(np.uint16) for _ in range(4)]
    write_served_images(root / 'capture_frames', served)
    client.serve(root / 'capture_frames')
    out = tmp_path / 'captured'
    p = cli('capture', str(out), 'orange-real/s9/p00', '--json', '--frames', '2',
            domain_id=client.domain_id)
    assert p.returncode == 0, p.stderr + p.stdout
    (answer,) = json.loads(p.stdout)
    assert answer['success'] and answer['images_captured'] == 32, answer
    captured = load_capture(out, cache=False)
    assert captured.sample_names == ['orange-real/s9/p00']
    assert captured.models.shape == (1, 4, 8, 48, 64)
    assert captured.rig.bit_depth == 10
    assert np.isfinite(captured.models).all()
    assert 0 <= captured.models.min() and captured.models.max() <= 1023


def test_calibrate_runs_to_the_end_and_writes_a_noise_file(graph, tmp_path):
    client, root = graph
    rng = np.random.default_rng(7)
    # 3 levels x 4 frames of a smooth target with affine noise (var = 0.7 mean + 66)
    target = np.linspace(0.2, 1.0, 64)[None, :] * np.linspace(0.6, 1.0, 48)[:, None]
    frames = []
    for level in (150.0, 400.0, 800.0):
        mean = target * level
        for _ in range(4):
            gray = mean + rng.standard_normal(mean.shape) * np.sqrt(0.7 * mean + 66.0)
            frames.append(encode_mono16(gray, 10))
    write_served_images(root / 'calibration_frames', frames)
    client.serve(root / 'calibration_frames')
    noise_file = tmp_path / 'noise.yaml'
    p = cli('calibrate', str(noise_file), '--exposure-us', '5000', '--gain-db', '15',
            '--frames', '4', '--levels', '3', '--json', domain_id=client.domain_id)
    assert p.returncode == 0, p.stderr + p.stdout
    r = json.loads(p.stdout)
    assert r['success'] and r['output_path'] == str(noise_file), r
    fit = load_noise_file(noise_file)
    assert (fit.gain_db, fit.exposure_ms) == (15.0, 5.0)
    assert fit.sigma_p2 > 0 and fit.sigma_r2 > 0


def test_classify_returns_the_label_of_the_sample_the_camera_shows(graph, stage_modelset, tmp_path):
    client, root = graph
    # first call: the classifier lights its patterns; the camera shows random frames at 120 px
    rng = np.random.default_rng(8)
    write_served_images(root / 'noise120', [(rng.integers(0, 1024, (120, 120)) << 6).astype(np.uint16)
                                            for _ in range(3)])
    client.serve(root / 'noise120')
    client.illumination.clear()
    r = client.classify()
    assert r.success, r.message
    assert r.label in r.class_names
    client.spin_until(lambda: len(client.illumination) >= r.images_used, 10.0, 'the triggers')
    # second call: the camera serves the sample rendered under exactly those patterns
    camera = SimCamera(stage_modelset, sample=SAMPLE, noise='none')
    renders = [camera.capture(np.asarray(m.intensities), m.exposure_us, m.gain_db)
               for m in client.illumination[:r.images_used]]
    write_served_images(root / 'sample120', renders)
    client.serve(root / 'sample120')
    r = client.classify()
    assert r.success, r.message
    assert r.label.split('-')[0] == SAMPLE.split('-')[0], (r.label, r.scores)


FAIL_FIRST_BUFFER = ('ForceFailedBufferCount=1', 'ForceFailedBuffer')   # the emulator's fault


def test_a_lost_frame_ends_a_classify_request_with_the_cameras_reason(graph):
    client, root = graph
    rng = np.random.default_rng(9)
    write_served_images(root / 'lost120', [(rng.integers(0, 1024, (120, 120)) << 6).astype(np.uint16)
                                           for _ in range(3)])
    client.serve(root / 'lost120', *FAIL_FIRST_BUFFER)
    r = client.classify()   # timeout_s 20: only the camera's notice gives this message
    assert not r.success
    assert 'was lost by the camera (camera/frame_lost): failed buffer: The buffer was incompletely ' \
           'grabbed.' in r.message, r.message
    assert 'did not arrive' not in r.message, r.message


def test_a_lost_frame_ends_a_capture_with_the_cameras_reason(graph, tmp_path):
    client, root = graph
    rng = np.random.default_rng(10)
    write_served_images(root / 'lost_capture', [(rng.integers(0, 800, (48, 64)) << 6).astype(np.uint16)
                                                for _ in range(4)])
    client.serve(root / 'lost_capture', *FAIL_FIRST_BUFFER)
    p = cli('capture', str(tmp_path / 'captured'), 'orange-real/s9/p01', '--json', '--frames', '2',
            domain_id=client.domain_id)
    assert p.returncode != 0
    assert 'failed buffer: The buffer was incompletely grabbed.' in p.stdout + p.stderr, p.stdout + p.stderr
    assert 'did not arrive' not in p.stdout + p.stderr
