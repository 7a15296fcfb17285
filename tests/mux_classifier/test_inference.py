"""The inference core without ROS: plan, mono16 decoding, training-equal preparation, matching."""
import math
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from lightstage_physics.render import render_led_patterns
from lightstage_camera.sim_camera import SimCamera
from mux_classifier.artifact import ArtifactError
from mux_classifier.inference import (ImageMatcher, InferenceError, MissingImagesError,
                                      classify_frames, classify_on_stage, image_from_buffer,
                                      mono16_to_gray, plan_acquisition)

from helpers.suite import TRAIN_SITE_PATTERNS

pytestmark = pytest.mark.process


def test_plan_takes_the_first_k_patterns_k_a_trained_count_and_the_artifacts_setting(stage_artifact):
    assert stage_artifact.n_images == [4, 8]
    for asked, k in [(0, 8), (8, 8), (100, 8), (7, 4), (4, 4)]:
        plan = plan_acquisition(stage_artifact, asked)
        assert plan.n_images == k
        np.testing.assert_array_equal(plan.led_patterns, stage_artifact.led_patterns[:, :k])
    plan = plan_acquisition(stage_artifact, 4)
    # per-colour: image c of site column 0 lights LED site*4 + c of the column's sites
    sites = np.flatnonzero(TRAIN_SITE_PATTERNS[:, 0])
    for c in range(4):
        assert np.flatnonzero(plan.led_patterns[:, c]).tolist() == (sites * 4 + c).tolist()
    assert plan.exposure_us == 22500 and plan.gain_db == 17.5  # sigma3
    with pytest.raises(InferenceError, match=r'smallest image count.*\(4\).*\[4, 8\]'):
        plan_acquisition(stage_artifact, 3)
    noise_free = replace(stage_artifact, noise=None)
    plan = plan_acquisition(noise_free, 0)
    assert plan.exposure_us == 0 and math.isnan(plan.gain_db)  # driver / camera defaults
    # a setting no camera takes (nor the Pattern message: uint32 us, float32 dB) is refused
    # when the artifact is made or loaded (the shared ranges), so never sent
    for exposure_ms, gain_db, field in [(4_294_968.0, 0.0, 'exposure_ms'), (22.5, 1e39, 'gain_db')]:
        with pytest.raises(ArtifactError, match=f'noise setting {field} = .* is out of range'):
            replace(stage_artifact, noise=dict(stage_artifact.noise, exposure_ms=exposure_ms,
                                               gain_db=gain_db))


def test_image_from_buffer_decodes_mono16_with_row_padding_and_either_byte_order():
    image = np.arange(12, dtype=np.uint16).reshape(3, 4) * 4097
    padded = np.zeros((3, 6), np.uint16)
    padded[:, :4] = image
    np.testing.assert_array_equal(image_from_buffer(padded.astype('<u2').tobytes(), 3, 4, 12, 'mono16'), image)
    np.testing.assert_array_equal(
        image_from_buffer(image.astype('>u2').tobytes(), 3, 4, 8, 'mono16', is_bigendian=True), image)
    with pytest.raises(ValueError, match="encoding is 'rgb8'.*mono16"):
        image_from_buffer(bytes(24), 3, 4, 8, 'rgb8')
    with pytest.raises(ValueError, match='holds 10 bytes'):
        image_from_buffer(bytes(10), 3, 4, 8, 'mono16')


def test_mono16_to_gray_undoes_the_msb_alignment():
    raw = np.array([[0, 1 << 6, 1023 << 6, (512 << 6) + 32]], np.uint16)
    np.testing.assert_array_equal(mono16_to_gray(raw, 10), [[0, 1, 1023, 512.5]])
    np.testing.assert_array_equal(mono16_to_gray(np.array([4095 << 4], np.uint16), 12), [4095])


def _upsampled(modelset, factor=2):
    """The same scene seen by a camera with `factor` x the resolution (each pixel a block)."""
    from lightstage_physics.scene_models import ModelSet
    big = modelset.models.repeat(factor, axis=-1).repeat(factor, axis=-2)
    return ModelSet(big, modelset.labels, modelset.class_names, modelset.sample_names,
                    modelset.pose_index, modelset.instance,
                    replace(modelset.rig, image_size=big.shape[-2:]))


def test_frames_are_prepared_as_training_renders_them(stage_modelset, stage_artifact):
    """A 240 px camera, decoded and downscaled by the classifier, gives the 120 px render the
    trainer makes from the same models (`ModelSet.downscaled` + `render_led_patterns`)."""
    big = _upsampled(stage_modelset.subset([5]))
    cam = SimCamera(big, sample=0, noise='none')
    plan = plan_acquisition(stage_artifact, 8)
    frames = [cam.capture(p, plan.exposure_us, plan.gain_db) for p in plan.led_patterns.T]
    prediction, stack = classify_frames(stage_artifact, frames, bit_depth=10)
    training = render_led_patterns(big.downscaled(120), plan.led_patterns)[0]
    assert stack.shape == (8, 120, 120)
    np.testing.assert_allclose(stack, np.clip(training, 0, 1023), atol=0.5)  # camera rounds
    expected = stage_artifact.predict_stack(np.clip(training, 0, 1023))
    assert prediction.label == expected.label and prediction.n_images == 8
    np.testing.assert_allclose(prediction.scores, expected.scores, atol=0.05)


def test_classify_frames_rejects_images_it_cannot_use(stage_artifact):
    with pytest.raises(InferenceError, match='at least 120x120'):
        classify_frames(stage_artifact, [np.zeros((60, 60), np.uint16)] * 4)
    with pytest.raises(InferenceError, match='differ in size'):
        classify_frames(stage_artifact, [np.zeros((120, 120), np.uint16), np.zeros((240, 240), np.uint16)])
    with pytest.raises(InferenceError, match='for \\[4, 8\\] images, not 3'):
        classify_frames(stage_artifact, [np.zeros((120, 120), np.uint16)] * 3)


def test_matcher_orders_by_stamp_not_arrival_and_keeps_early_images():
    matcher = ImageMatcher(capacity=8)
    stamps = [1_000, 2_000, 3_000]
    images = {s: np.full((2, 2), s // 1000, np.uint16) for s in stamps}
    matcher.add(3_000, images[3_000])  # before anyone asked: buffered
    matcher.add(999, np.zeros((2, 2), np.uint16))  # an unrelated frame
    matcher.add(1_000, images[1_000])

    def late():
        time.sleep(0.1)
        matcher.add(2_000, images[2_000])

    threading.Thread(target=late).start()
    got, last_arrival = matcher.collect(stamps, timeout_s=5.0)
    assert [int(g[0, 0]) for g in got] == [1, 2, 3]
    assert last_arrival >= max(0, time.time_ns() - 5_000_000_000)
    assert len(matcher) == 1  # collected images leave the buffer, the unrelated one stays


def test_matcher_timeout_names_the_missing_and_the_unusable_images():
    matcher = ImageMatcher()
    matcher.add(1_500_000_000_000_000_001, np.zeros((2, 2), np.uint16))
    matcher.add(1_500_000_000_000_000_003, None, error="image encoding is 'rgb8'")
    start = time.monotonic()
    with pytest.raises(MissingImagesError) as info:
        matcher.collect([1_500_000_000_000_000_001, 1_500_000_000_000_000_002,
                         1_500_000_000_000_000_003], timeout_s=0.2, sequences=[7, 8, 9])
    assert 0.2 <= time.monotonic() - start < 2.0
    message = str(info.value)
    assert ('1 of 3 images did not arrive within 0.2 s: image 2 (trigger sequence 8, '
            'stamp 1500000000.000000002)') in message
    assert "image 3 (trigger sequence 9, stamp 1500000000.000000003) is unusable: image encoding is 'rgb8'" in message
    assert info.value.missing == [1, 2]
    assert len(matcher) == 2  # nothing was consumed by a failed collect


def test_a_lost_frame_notice_ends_the_collect_at_once_with_the_cameras_reason():
    from types import SimpleNamespace
    matcher = ImageMatcher()
    stamps = [1_500_000_000_000_000_001, 1_500_000_000_000_000_002, 1_500_000_000_000_000_003]
    notice = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=1_500_000_000, nanosec=2)),
                             sequence=8, reason='failed buffer: The buffer was incompletely grabbed.')

    def camera():
        matcher.add(stamps[0], np.zeros((2, 2), np.uint16))
        matcher.add_lost_message(notice)   # the third image never comes
    threading.Thread(target=camera).start()
    # a timeout far beyond the test's own: only the notice can end this collect with this message
    with pytest.raises(MissingImagesError) as info:
        matcher.collect(stamps, timeout_s=600.0, sequences=[7, 8, 9])
    message = str(info.value)
    assert ('image 2 (trigger sequence 8, stamp 1500000000.000000002) was lost by the camera '
            '(camera/frame_lost): failed buffer: The buffer was incompletely grabbed.') in message
    assert 'did not arrive' not in message   # the third is on its way, not late
    assert 'the other 1 image(s) still on their way' in message
    assert info.value.missing == [1]


def test_frames_lost_for_one_reason_are_named_together():
    matcher = ImageMatcher()
    for stamp in (11, 12):
        matcher.add_lost(stamp, 'camera not ready: no capture folder')
    with pytest.raises(MissingImagesError) as info:
        matcher.collect([11, 12], timeout_s=600.0, sequences=[1, 2])
    assert str(info.value) == ('image 1 (trigger sequence 1, stamp 0.000000011), image 2 (trigger '
                               'sequence 2, stamp 0.000000012) were lost by the camera '
                               '(camera/frame_lost): camera not ready: no capture folder')


def test_matcher_keeps_only_the_most_recent_images():
    matcher = ImageMatcher(capacity=3)
    for s in range(5):
        matcher.add(s, np.zeros((1, 1), np.uint16))
    assert len(matcher) == 3 and matcher.evicted == 2
    with pytest.raises(MissingImagesError, match='image 1 '):
        matcher.collect([0, 4], timeout_s=0.01)


def test_classify_on_stage_lights_the_plan_and_matches_frames_delivered_out_of_order(
        stage_modelset, stage_artifact):
    name = 'orange-real/s1/p01'
    camera = SimCamera(stage_modelset, sample=name, noise='auto', seed=2)
    matcher = ImageMatcher()
    lit = []

    def apply(plan, timeout_s):
        lit.append(plan)
        stamps = [1_700_000_000_000_000_000 + 1_000_000 * i for i in range(plan.n_images)]
        frames = [camera.capture(p, plan.exposure_us, plan.gain_db) for p in plan.led_patterns.T]
        # the camera answers in reverse, partly before the driver's reply is back
        for s, f in list(zip(stamps, frames))[::-1][:2]:
            matcher.add(s, f)
        rest = list(zip(stamps, frames))[::-1][2:]
        threading.Thread(target=lambda: [matcher.add(s, f) for s, f in rest]).start()
        apply.frames = frames
        return stamps, list(range(10, 10 + plan.n_images))

    result = classify_on_stage(stage_artifact, apply, matcher, max_images=8, timeout_s=5.0)
    (plan,) = lit
    assert plan.n_images == 8 and result.images_used == 8
    assert result.sequences == list(range(10, 18))
    expected = np.stack([mono16_to_gray(f) for f in apply.frames])  # 120 px: no downscale
    np.testing.assert_array_equal(result.stack, expected)  # pattern order, not arrival order
    assert result.label == stage_artifact.predict_stack(expected).label == 'orange-real'
    assert result.class_names == stage_artifact.class_names and result.scores.shape == (4,)
    assert result.compute_ms > 0


def test_classify_on_stage_reports_driver_failures_and_short_answers(stage_artifact):
    def refused(plan, timeout_s):
        raise InferenceError('the driver did not apply the patterns: not active')

    with pytest.raises(InferenceError, match='not active'):
        classify_on_stage(stage_artifact, refused, ImageMatcher())
    with pytest.raises(InferenceError, match='asked for 4 triggers but the driver reported 1'):
        classify_on_stage(stage_artifact, lambda plan, t: ([1], [1]), ImageMatcher(), max_images=4)
    with pytest.raises(MissingImagesError, match='4 of 4 images did not arrive within'):
        classify_on_stage(stage_artifact, lambda plan, t: ([1, 2, 3, 4], [1, 2, 3, 4]),
                          ImageMatcher(), max_images=4, timeout_s=0.3)


def test_the_cores_do_not_load_rclpy():
    import subprocess
    import sys
    code = ('import sys, lightstage_camera.sim_camera, lightstage_camera.camera_backend, '
            'mux_classifier.inference; print("rclpy" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == 'False'
