"""Graded levels through the graph on the simulated stage.

1. The driver node (its own process) on a graded Python firmware: a drive of 0.5 for 10 ms
   lights the LEDs for the same time as 1.0 for 5 ms (on the firmware's pins), /illumination
   carries the applied (rounded) drives, and an image rendered from each IlluminationState
   the way the camera node renders it (SimCamera with exposure_scales_light: the light
   integrated over the exposure) is the same within noise.
2. A trained artifact whose patterns are graded runs through `lightstage classify`: driver
   (graded simulator), camera and classifier as processes.
"""
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lightstage_driver.sim_backend import PythonSimBackend

from driver_helpers import wait_until

pytestmark = pytest.mark.ros
rclpy = pytest.importorskip('rclpy')

from lightstage_camera.camera_backend import Trigger  # noqa: E402
from lightstage_camera.sim_camera import SimCamera  # noqa: E402

from test_driver_node import Client, own_domain, start_node, stop_node  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent / 'firmware'))
from graded_pins import on_times_us  # noqa: E402

LEDS = list(range(32))     # every LED: the most light a 5 ms exposure gets


@pytest.fixture(scope='module')
def graded_rig():
    backend = PythonSimBackend(pwm_bits=8)
    backend.start()
    proc = start_node(backend.port, 'graded_driver_under_test', domain_id=own_domain(40))
    client = Client('graded_driver_under_test', own_domain(40))
    yield backend, client
    client.close()
    stop_node(proc)
    backend.close()


def drive(level):
    pattern = np.zeros(32)
    pattern[LEDS] = level
    return pattern


def test_half_level_for_10_ms_images_like_full_level_for_5_ms(graded_rig, stage_modelset):
    backend, client = graded_rig
    assert client.apply([drive(0.0)], trigger=False).success     # the service is up
    backend.reset_observations()
    client.illumination.clear()
    states = []
    for level, exposure_us in ((0.5, 10_000), (1.0, 5_000), (0.5, 5_000)):
        response = client.apply([drive(level)], exposure_us=exposure_us)
        assert response.success, response.message
        if level == 0.5:   # 0.5 is level 128 of 255: the reply says so
            assert "rounded to the board's 8-bit levels" in response.message, response.message
    assert client.spin_until(lambda: len(client.illumination) == 3)
    states = list(client.illumination)
    # /illumination carries what was applied: 128/255 for 0.5
    assert np.allclose(states[0].intensities[LEDS], 128 / 255)
    assert np.allclose(states[1].intensities[LEDS], 1.0)
    # on the firmware's pins: the same on-time (128/255 x 10 ms = 5.02 ms vs 5 ms)
    assert wait_until(lambda: len(backend.trigger_pulses()) == 3, 2.0)
    ons = on_times_us(backend.led_words(), backend.trigger_pulses())
    assert np.allclose(ons[0][LEDS], 128 / 255 * 10_000, atol=0.5)
    assert np.allclose(ons[1][LEDS], 5_000, atol=0.5)

    camera = SimCamera(stage_modelset, sample=0, noise='auto', seed=7, exposure_scales_light=True)
    images, variances, cleans = [], [], []
    for msg in states:
        trig = Trigger(0, int(msg.sequence), np.asarray(msg.intensities, dtype=np.float32),
                       int(msg.exposure_us), float(msg.gain_db))
        clean = camera.render(trig.led_intensities) * (trig.exposure_us / stage_modelset.rig.exposure_us)
        assert clean.max() < stage_modelset.max_level       # no clipping: the comparison is linear
        cleans.append(clean)
        variances.append(camera.noise_model(trig.exposure_us, trig.gain_db).variance(clean))
        images.append(camera.capture(trig.led_intensities, trig.exposure_us, trig.gain_db).astype(np.float64)
                      / 2 ** (16 - camera.bit_depth))
    half_10, full_5, half_5 = images
    # the same light: means within the level step (1/255) plus the noise of a mean
    noise_of_mean = np.sqrt((variances[0] + variances[1]).mean() / half_10.size)
    assert abs(half_10.mean() / full_5.mean() - 1) <= 1 / 255 + 4 * noise_of_mean / full_5.mean()
    # and pixel by pixel no more than the two frames' noise (plus 1 gray level of rounding)
    assert np.std(half_10 - full_5) <= 1.2 * np.sqrt((variances[0] + variances[1]).mean()) + 0.5
    # while half the light (0.5 for 5 ms) is clearly different: half the signal is missing
    assert (full_5 - half_5).mean() == pytest.approx(0.5 * cleans[1].mean(), rel=0.1)
    assert (full_5 - half_5).mean() > 20 * noise_of_mean


@pytest.fixture(scope='module')
def graded_artifact_path(stage_artifact_path, tmp_path_factory):
    """The stage's trained artifact with its patterns at drive 0.6 (level 153 of 255, exact)."""
    from dataclasses import replace

    from lightstage_camera.rig import site_to_led_patterns
    from mux_classifier.artifact import TrainedArtifact
    art = TrainedArtifact.load(stage_artifact_path)
    assert art.site_patterns is not None and set(np.unique(art.site_patterns)) <= {0.0, 1.0}
    site = art.site_patterns * np.float32(0.6)
    graded = replace(art, site_patterns=site, led_patterns=site_to_led_patterns(site))
    path = tmp_path_factory.mktemp('graded') / 'graded.npz'
    graded.save(path)
    return path


def test_a_graded_artifact_runs_through_lightstage_classify(stage_capture, graded_artifact_path,
                                                            tmp_path):
    from lightstage_bringup.supervisor import Supervisor
    from lightstage_interfaces.msg import IlluminationState
    from mux_classifier.artifact import TrainedArtifact

    from suite_helpers import GraphClient, fresh_domain_id, start_nodes, write_params
    artifact = TrainedArtifact.load(graded_artifact_path)
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', {
        'driver': {'port': 'sim://?pwm_bits=8'},
        'camera': {'capture_dir': str(stage_capture), 'sample': 'banana-real/s1/p00', 'seed': 3},
        'classifier': {'artifact_path': str(graded_artifact_path), 'timeout_s': 10.0},
    })
    client = GraphClient(domain_id)
    seen = []
    client.node.create_subscription(IlluminationState, '/illumination', seen.append, 100)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params)
            p = subprocess.run([sys.executable, '-m', 'lightstage_bringup.classify_cli', '--domain-id',
                                str(domain_id), '--json', '--max-images', '4'],
                               capture_output=True, text=True, timeout=90)
            assert p.returncode == 0, p.stderr
            answer = json.loads(p.stdout)
            assert answer['success'] and answer['images_used'] == 4, answer
            assert answer['label'] in answer['class_names']
            client.spin_until(lambda: len(seen) >= 4, 10.0, 'the classify call\'s /illumination')
    finally:
        client.close()
    # the stage lit the artifact's graded patterns: level 153 = 0.6 exactly, in image order
    assert len(seen) >= 4
    lit = np.array([np.asarray(m.intensities) for m in seen[:4]])
    assert np.allclose(lit, artifact.led_patterns[:, :4].T, atol=1e-6)
    assert np.allclose(np.unique(lit), [0.0, 0.6])
