"""Graded levels through the graph on the simulated stage.

1. The driver node and the camera node (sim backend, `exposure_scales_light: true`), each its
   own process, on a graded Python firmware: a drive of 0.5 for 10 ms lights the LEDs for the
   same time as 1.0 for 5 ms (on the firmware's pins), /illumination carries the applied
   (rounded) drives, and the two images the camera publishes on camera/image_raw (matched to
   the triggers by stamp) are the same within noise, while 0.5 for 5 ms (half the light) is not.
2. A trained artifact whose patterns are graded runs through `lightstage classify`: driver
   (graded simulator), camera and classifier as processes.
"""
import math

import numpy as np
import pytest

from lightstage_driver.sim_backend import PythonSimBackend

from helpers.driver import wait_until

pytestmark = [pytest.mark.ros, pytest.mark.process]
rclpy = pytest.importorskip('rclpy')

from helpers.graded_pins import on_times_us  # noqa: E402

LEDS = list(range(32))     # every LED: the most light a 5 ms exposure gets
SAMPLE = 'banana-real/s1/p00'
GAIN_DB = 15.0
# (drive, exposure): 0.5 is level 128 of 255, lit for 128/255 of 10 ms = 5.02 ms
SHOTS = ((0.5, 10_000), (1.0, 5_000), (0.5, 5_000))


def drive(level):
    pattern = np.zeros(32, np.float32)
    pattern[LEDS] = level
    return pattern


def frame_model(stage_modelset, intensities, exposure_us):
    """The exact per-pixel mean and variance of the sim camera's frame of one trigger
    (`sim_camera.frame_moments`: the noise model's Gaussian, clipped and rounded), and the
    noise-free light it integrated."""
    from lightstage_camera.sim_camera import SimCamera, frame_moments
    camera = SimCamera(stage_modelset, sample=SAMPLE, noise='auto', default_gain_db=GAIN_DB)
    light = camera.render(intensities).astype(np.float64) * (exposure_us / stage_modelset.rig.exposure_us)
    variance = camera.noise_model(exposure_us, GAIN_DB).variance(light) * stage_modelset.noise_scale
    mean, var = frame_moments(light, variance, stage_modelset.max_level)
    return light, mean, var


def test_half_level_for_10_ms_images_like_full_level_for_5_ms_through_the_graph(
        stage_capture, stage_modelset, tmp_path):
    from lightstage_bringup.supervisor import Supervisor
    from lightstage_graph.frames import ImageMatcher, mono16_to_gray
    from lightstage_graph.names import APPLY_PATTERNS_SERVICE, ILLUMINATION_TOPIC, IMAGE_TOPIC
    from lightstage_graph.qos import ILLUMINATION_QOS, IMAGE_QOS
    from lightstage_graph.stamps import stamp_to_ns
    from lightstage_interfaces.msg import IlluminationState, Pattern
    from lightstage_interfaces.srv import ApplyPatterns
    from sensor_msgs.msg import Image

    from helpers.suite import GraphClient, fresh_domain_id, stage_graph_params, start_nodes, write_params
    backend = PythonSimBackend(pwm_bits=8)    # the driver's firmware, its pins seen from here
    backend.start()
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', stage_graph_params(
        stage_capture, SAMPLE, 7, driver={'port': backend.port},
        camera={'noise': 'auto', 'exposure_scales_light': True}))
    client = GraphClient(domain_id)
    states, matcher = [], ImageMatcher(capacity=8)
    client.node.create_subscription(IlluminationState, ILLUMINATION_TOPIC, states.append,
                                    ILLUMINATION_QOS)
    images_sub = client.node.create_subscription(Image, IMAGE_TOPIC, matcher.add_message, IMAGE_QOS)
    apply = client.service(ApplyPatterns, APPLY_PATTERNS_SERVICE)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera'], domain_id, params)  # and its links
            client.spin_until(lambda: images_sub.get_publisher_count() > 0, 10.0,
                              'the camera\'s image publisher')
            # a round trip without a trigger: the service's reply path is matched too
            dark = ApplyPatterns.Request(patterns=[Pattern(intensities=drive(0.0))], trigger=False)
            assert client.call_until_answered(apply, dark).success
            backend.reset_observations()
            responses = []
            for level, exposure_us in SHOTS:
                request = ApplyPatterns.Request(trigger=True, patterns=[
                    Pattern(intensities=drive(level), exposure_us=exposure_us, gain_db=GAIN_DB)])
                response = client.result(apply.call_async(request), 10.0, 'the driver\'s reply')
                assert response.success, response.message
                if level == 0.5:   # 0.5 is level 128 of 255: the reply says so
                    assert "rounded to the board's 8-bit levels" in response.message, response.message
                responses.append(response)
            client.spin_until(lambda: len(matcher) >= 3 and len(states) >= 3, 10.0,
                              lambda: f'3 images and 3 trigger states (have {len(matcher)}, {len(states)})')
            # the images of these triggers, by the stamps the driver replied: never by arrival
            stamps = [stamp_to_ns(r.trigger_stamps[0]) for r in responses]
            frames, _ = matcher.collect(stamps, 0.0, [r.sequences[0] for r in responses])
    finally:
        client.close()
        backend.close()

    # /illumination carries what was applied: 128/255 for 0.5
    assert [s.request_id for s in states] == [r.request_id for r in responses]
    applied = [np.asarray(s.intensities, np.float64) for s in states]
    assert np.allclose(applied[0][LEDS], 128 / 255) and np.allclose(applied[2][LEDS], 128 / 255)
    assert np.allclose(applied[1][LEDS], 1.0)
    # on the firmware's pins: the same on-time (128/255 x 10 ms = 5.02 ms vs 5 ms)
    assert wait_until(lambda: len(backend.trigger_pulses()) == 3, 2.0)
    ons = on_times_us(backend.led_words(), backend.trigger_pulses())
    assert np.allclose(ons[0][LEDS], 128 / 255 * 10_000, atol=0.5)
    assert np.allclose(ons[1][LEDS], 5_000, atol=0.5)
    assert np.allclose(ons[2][LEDS], 128 / 255 * 5_000, atol=0.5)

    # what the camera node published, against the noise model of each frame
    half_10, full_5, half_5 = (mono16_to_gray(f, stage_modelset.rig.bit_depth).astype(np.float64)
                               for f in frames)
    models = [frame_model(stage_modelset, a, e) for a, (_l, e) in zip(applied, SHOTS)]
    (light_h10, mean_h10, var_h10), (light_f5, mean_f5, var_f5), (_l, mean_h5, var_h5) = models
    assert light_f5.max() < stage_modelset.max_level / 2   # far from clipping: a linear comparison
    n = full_5.size

    def mean_gap(a, b, var_a, var_b):
        """Observed mean of a - b, and the standard deviation of that mean (independent
        pixels, independent frames)."""
        return float((a - b).mean()), math.sqrt(float((var_a + var_b).sum())) / n

    # the same light: the means differ by no more than the level step (128/255 x 2 = 1 + 1/255
    # of the light) plus 4 standard deviations of the noise of a mean
    gap, sd = mean_gap(half_10, full_5, var_h10, var_f5)
    assert abs(gap) <= float(light_f5.mean()) / 255 + 4 * sd, (gap, sd)
    # ... which is what the model predicts, step included
    assert abs(gap - float((mean_h10 - mean_f5).mean())) <= 4 * sd
    # and pixel by pixel the frames differ by their noise only: mean squared difference over
    # its variance is 1 (within 6 of its standard errors, measured), not more
    z2 = (half_10 - full_5) ** 2 / (var_h10 + var_f5)
    assert z2.mean() <= 1 + 6 * z2.std() / math.sqrt(n), z2.mean()
    # while half the light (0.5 for 5 ms) is clearly different: 127/255 of the signal is missing
    gap_half, sd_half = mean_gap(full_5, half_5, var_f5, var_h5)
    expected = float((mean_f5 - mean_h5).mean())
    assert expected > 20 * sd_half
    assert abs(gap_half - expected) <= 4 * sd_half, (gap_half, expected, sd_half)


@pytest.fixture(scope='module')
def graded_artifact_path(stage_artifact_path, tmp_path_factory):
    """The stage's trained artifact with its patterns at drive 0.6 (level 153 of 255, exact)."""
    from dataclasses import replace

    from lightstage_physics.rig import site_to_led_patterns
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
    from mux_classifier.artifact import TrainedArtifact

    from helpers.suite import (classify_on_the_stage_graph, fresh_domain_id, stage_graph_params,
                               write_params)
    artifact = TrainedArtifact.load(graded_artifact_path)
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', stage_graph_params(
        stage_capture, 'banana-real/s1/p00', 3, graded_artifact_path,
        driver={'port': 'sim://?pwm_bits=8'}))
    answer, seen = classify_on_the_stage_graph(params, domain_id, '--max-images', '4',
                                               n_illumination=4)
    assert answer['success'] and answer['images_used'] == 4, answer
    assert answer['label'] in answer['class_names']
    # the stage lit the artifact's graded patterns: level 153 = 0.6 exactly, in image order
    assert len(seen) >= 4
    lit = np.array([np.asarray(m.intensities) for m in seen[:4]])
    assert np.allclose(lit, artifact.led_patterns[:, :4].T, atol=1e-6)
    assert np.allclose(np.unique(lit), [0.0, 0.6])
