"""Shared by the node tests: a tiny synthetic capture and an artifact trained on it (once per run)."""
import numpy as np
import pytest

from node_helpers import TRAIN_SITE_PATTERNS


@pytest.fixture(scope='session')
def stage_capture(tmp_path_factory):
    """2 object types x {fake, real} x 2 samples x 3 poses at 120 px: the feature size, so
    rendering it stays fast (a few s); the downscale path is tested on small random models."""
    from lightstage_camera import synth
    return synth.generate(tmp_path_factory.mktemp('nodes') / 'capture', image_size=120,
                          n_samples_per_class=2, n_poses=3, object_types=('banana', 'orange'),
                          n_jobs=2)


@pytest.fixture(scope='session')
def stage_modelset(stage_capture):
    from lightstage_camera.capture_format import load_capture
    return load_capture(stage_capture)


@pytest.fixture(scope='session')
def stage_artifact_path(stage_capture, tmp_path_factory):
    """A per-colour artifact (2 site patterns -> classifiers for 4 and 8 images), sigma3 noise,
    trained the way `lightstage train` does: at 120 px from the capture."""
    from lightstage_camera.capture_format import load_capture
    from mux_trainer.baselines import FixedPatternClassifier
    modelset = load_capture(stage_capture, downscale_to=120)
    model = FixedPatternClassifier(patterns=TRAIN_SITE_PATTERNS, n_repeats=10, noise='sigma3',
                                   seed=0).fit(modelset)
    path = tmp_path_factory.mktemp('artifact') / 'classifier.npz'
    model.to_artifact().save(path)
    return path


@pytest.fixture(scope='session')
def stage_artifact(stage_artifact_path):
    from mux_classifier.model import TrainedArtifact
    return TrainedArtifact.load(stage_artifact_path)
