"""`lightstage classify` on a learned artifact through the real graph --
driver (simulated firmware), camera and classifier, each its own process. A graded model
runs on a graded board (pwm_bits 8), an on/off one on an on/off board (pwm_bits 0, the
authors' rig); the stage lights the learned levels in image order."""
import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.process]
rclpy = pytest.importorskip('rclpy')


def test_a_learned_artifact_classifies_on_the_stage(stage_capture, stage_learned_artifact_path,
                                                    tmp_path):
    from mux_classifier.artifact import TrainedArtifact

    from helpers.suite import (classify_on_the_stage_graph, fresh_domain_id, stage_graph_params,
                               write_params)
    artifact = TrainedArtifact.load(stage_learned_artifact_path)
    on_off = bool(np.isin(artifact.led_patterns, (0, 1)).all())
    assert artifact.mode == 'learned' and artifact.n_images == [4]
    assert artifact.learned.class_groups is not None   # fruit types: the head gated by type
    domain_id = fresh_domain_id()
    params = write_params(tmp_path / 'params.yaml', stage_graph_params(
        stage_capture, 'orange-real/s1/p00', 3, stage_learned_artifact_path,
        driver={'port': 'sim' if on_off else 'sim://?pwm_bits=8'}))
    answer, seen = classify_on_the_stage_graph(params, domain_id, n_illumination=4)
    assert answer['success'] and answer['images_used'] == 4, answer
    assert answer['label'] in answer['class_names'] == artifact.class_names
    # the stage lit the learned levels, in image order: exactly (on/off), or rounded to the
    # graded board's 8-bit steps (half a step at most)
    lit = np.array([np.asarray(m.intensities) for m in seen[:4]])
    assert np.abs(lit - artifact.led_patterns.T).max() <= (0 if on_off else 0.5 / 255 + 1e-6)
    if not on_off:
        assert len(np.unique(lit)) > 2  # graded levels, not on/off
    # the scores are the gated head's margins for the images the node saw: finite, varied,
    # positive for the label only
    scores = np.array(answer['scores'])
    assert np.isfinite(scores).all() and scores.std() > 0
    assert scores.argmax() == answer['class_names'].index(answer['label'])
    assert (scores > 0).sum() <= 1
