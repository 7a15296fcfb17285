"""Suite-wide setup: every ROS participant of the test run stays on loopback.

This runs before any test module imports rclpy, so in-process nodes get LOCALHOST
discovery, the project's Fast DDS profile and a domain id of this run's own (tests that
start processes choose their own ids through `lightstage_graph.ros_env`).

Loading this file also puts tests/ on sys.path (pytest's "prepend" import mode), so the
test directories import `suite_helpers`, the helpers they share.

The fixtures below are the stage the node and recording tests share: a tiny synthetic
capture and an artifact trained on it, made once per run.
"""
import os
import signal

import pytest

from lightstage_graph.ros_env import apply_ros_environment

# A run started with SIGINT ignored (a background job of a non-interactive shell, nohup, some
# CI runners) hands SIG_IGN on to every process it starts, and the tests that stop nodes and
# CLIs with Ctrl-C then fail: give the run Python's own handler, which exec resets to the
# default in the children.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

TEST_RUN_DOMAIN_ID = 100 + os.getpid() % 100
apply_ros_environment(domain_id=int(os.environ.get('LIGHTSTAGE_TEST_DOMAIN_ID', TEST_RUN_DOMAIN_ID)))


def pytest_report_header(config):
    from suite_helpers import network_interfaces
    interfaces = network_interfaces()
    if interfaces == ['lo']:
        return 'network: private namespace, loopback only (no packet can leave the machine)'
    return (f"network: the host's ({', '.join(interfaces) or 'unknown'}), not a private "
            f'namespace; scripts/run_tests.sh runs the suite in one where the platform allows')


@pytest.fixture(scope='session', autouse=True)
def rescue_dir(tmp_path_factory):
    """Captures that cannot be written keep their images in a rescue folder: the tests' (and
    the nodes they start, which inherit the environment) go to a temporary one, not ~/.cache."""
    path = tmp_path_factory.mktemp('rescued')
    os.environ['LIGHTSTAGE_RESCUE_DIR'] = str(path)
    return path


@pytest.fixture(scope='session')
def stage_capture(tmp_path_factory):
    """2 object types x {fake, real} x 2 samples x 3 poses at 120 px: the feature size, so
    rendering it stays fast (a few s); the downscale path is tested on small random models."""
    from lightstage_physics import synth
    return synth.generate(tmp_path_factory.mktemp('stage') / 'capture', image_size=120,
                          n_samples_per_class=2, n_poses=3, object_types=('banana', 'orange'),
                          n_jobs=2)


@pytest.fixture(scope='session')
def stage_modelset(stage_capture):
    from lightstage_physics.capture_format import load_capture
    return load_capture(stage_capture)


@pytest.fixture(scope='session')
def stage_artifact_path(stage_capture, tmp_path_factory):
    """A per-colour artifact (2 site patterns -> classifiers for 4 and 8 images), sigma3 noise,
    trained the way `lightstage train` does: at 120 px from the capture."""
    return _train_stage_artifact(stage_capture, tmp_path_factory, 'hog_grid')


@pytest.fixture(scope='session')
def stage_intensity_artifact_path(stage_capture, tmp_path_factory):
    """The same artifact on the pose-robust `intensity_stats` features."""
    return _train_stage_artifact(stage_capture, tmp_path_factory, 'intensity_stats')


def _train_stage_artifact(stage_capture, tmp_path_factory, features):
    from lightstage_physics.capture_format import load_capture
    from mux_trainer.baselines import FixedPatternClassifier
    from suite_helpers import TRAIN_SITE_PATTERNS
    modelset = load_capture(stage_capture, downscale_to=120)
    model = FixedPatternClassifier(patterns=TRAIN_SITE_PATTERNS, n_repeats=10, noise='sigma3',
                                   seed=0, features=features).fit(modelset)
    path = tmp_path_factory.mktemp('artifact') / f'classifier_{features}.npz'
    model.to_artifact().save(path)
    return path


@pytest.fixture(scope='session')
def stage_artifact(stage_artifact_path):
    from mux_classifier.artifact import TrainedArtifact
    return TrainedArtifact.load(stage_artifact_path)


@pytest.fixture(scope='session', params=[False, True], ids=['graded', 'on_off'])
def stage_learned_artifact_path(request, stage_capture, tmp_path_factory):
    """A learned artifact (4 exposures, graded or on/off levels, 3 steps: little learned, but
    a real one) trained on the stage capture the way `lightstage train --method learned` does."""
    from mux_trainer.training import train_from_capture
    path = tmp_path_factory.mktemp('learned') / f'learned_{request.param_index}.npz'
    train_from_capture(stage_capture, path, method='learned', max_images=4, steps=3,
                       binary=request.param, seed=0)
    return path
