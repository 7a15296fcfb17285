"""Suite-wide setup: every ROS participant of the test run stays on loopback.

This runs before any test module imports rclpy, so in-process nodes get LOCALHOST
discovery, the project's Fast DDS profile and a domain id of this run's own (tests that
start processes choose their own ids through `lightstage_graph.ros_env`).

The test directories import their helpers explicitly from the `helpers` package
(tests/helpers/; pytest.ini's `pythonpath = tests` puts tests/ on sys.path).

The fixtures below are the stage the node and recording tests share: a tiny synthetic
capture and an artifact trained on it, made once per run.
"""
import functools
import os
import re
import signal
from pathlib import Path

import pytest

from helpers.markers import ProcessGuard, declares_process
from helpers.workers import xdist_worker
from lightstage_graph.ros_env import apply_ros_environment

# A run started with SIGINT ignored (a background job of a non-interactive shell, nohup, some
# CI runners) hands SIG_IGN on to every process it starts, and the tests that stop nodes and
# CLIs with Ctrl-C then fail: give the run Python's own handler, which exec resets to the
# default in the children.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# each worker of a parallel run (pytest-xdist) its own: 100 + worker modulo the worker count
_WORKER, _WORKERS = xdist_worker()
TEST_RUN_DOMAIN_ID = 100 + _WORKER + _WORKERS * (os.getpid() % (100 // _WORKERS))
apply_ros_environment(domain_id=int(os.environ.get('LIGHTSTAGE_TEST_DOMAIN_ID', TEST_RUN_DOMAIN_ID)))


def pytest_report_header(config):
    from helpers.suite import network_interfaces
    interfaces = network_interfaces()
    if interfaces == ['lo']:
        return 'network: private namespace, loopback only (no packet can leave the machine)'
    return (f"network: the host's ({', '.join(interfaces) or 'unknown'}), not a private "
            f'namespace; scripts/run_tests.sh runs the suite in one where the platform allows')


# A test module whose tests start processes (node graphs, CLIs, Dask, simavr, a browser)
# declares it: `pytestmark = pytest.mark.process` (tests/helpers/markers.py); a module where
# one test does marks that test. Tests that use a fixture that starts the firmware (simavr, or
# the Python simulator's process) are `process` too, wherever they are. Every `fast` test runs
# under `ProcessGuard`, which fails it if it starts a process all the same.
PROCESS_FIXTURES = {
    'avr', 'wire',      # tests/lightstage_driver/firmware/conftest.py: the AVR in simavr
    'firmware', 'sim',  # tests/lightstage_driver/conftest.py: either firmware as a process
}
NOT_FAST = ('ros', 'process', 'slow')

# Tests that start no process but compute for seconds (searches, training, statistics over many
# renders; measured with `--durations=0`): `slow`. Whole modules (paths under tests/) where most
# tests do; single tests (any parametrization) elsewhere; and every test that needs the
# suite's rendered capture (`stage_capture`: seconds of rendering on two worker processes).
SLOW_MODULES = {
    'mux_trainer/test_greedy.py', 'mux_trainer/test_learned.py', 'mux_trainer/test_evaluation.py',
    'mux_trainer/test_cli_trainer.py', 'mux_trainer/test_search_features.py',
    'lightstage_physics/test_lowres.py', 'lightstage_physics/test_render_jax.py',
    'lightstage_camera/acquisition/test_calibration_coverage.py', 'lightstage_physics/test_plots_synth.py',
    'lightstage_camera/backends/test_aravis.py', 'lightstage_driver/test_fuzz.py',
    'mux_classifier/test_bow.py', 'mux_trainer/test_snr_optimal.py', 'mux_trainer/test_learned_cli.py',
}
SLOW_TESTS = {
    'lightstage_camera/acquisition/test_calibration_core.py::test_calibration_outputs_are_written_and_not_replaced_unless_asked',
    'lightstage_camera/test_bad_trigger_values.py::test_fuzz_trigger_values_never_escape_and_name_the_field',
    'lightstage_physics/test_capture_format.py::test_cache_gives_identical_arrays_and_tracks_changes',
    'lightstage_driver/test_faults.py::test_a_noisy_line_never_double_triggers',
    'lightstage_driver/test_faults.py::test_a_sequence_that_never_ends_on_a_dead_line_does_not_claim_the_leds_are_off',
    'lightstage_driver/test_faults.py::test_latency_within_the_timeout_is_fine_beyond_it_is_an_error',
    'lightstage_driver/test_faults.py::test_a_hung_firmware_gives_no_reply_error_in_time_and_its_watchdog_darkens',
    'lightstage_driver/test_faults.py::test_a_silent_device_is_not_taken_for_a_stage',
    'lightstage_driver/test_request_fuzz.py::test_every_field_is_checked_and_a_refusal_names_it',
    'lightstage_driver/test_schedule.py::test_off_instants_within_the_bound_and_latches_a_shift_out_apart',
    'mux_classifier/test_artifact.py::test_fuzz_malformed_files_raise_only_artifact_error',
    'mux_classifier/test_artifact.py::test_fuzz_every_header_field_out_of_range_is_refused_naming_it',
    'mux_classifier/test_bow.py::test_stacks_concatenate_per_image_histograms',
    'mux_classifier/test_feature_extractors.py::test_fit_never_sees_a_test_pose',
    'mux_classifier/test_feature_extractors.py::test_layout_is_per_image_and_prefix',
    'mux_classifier/test_stage_queue.py::test_a_call_with_nothing_ahead_always_starts_and_a_full_queue_refuses',
    'mux_trainer/test_baselines.py::test_snr_optimal_uses_the_multiplexer_matrix_and_scores_each_prefix',
    'mux_classifier/test_hog.py::test_other_configurations_match_skimage',
    'mux_classifier/test_hog.py::test_compiled_kernel_other_configurations',
    'mux_trainer/test_trainer_bad_values.py::test_train_out_replaces_an_artifact_and_with_force_anything',
}
SLOW_FIXTURES = {'stage_capture'}
# The longest modules (summed `--durations` of a full run, 40-90 s each) start first: pytest-xdist
# (`--dist loadfile`) hands modules to the workers in collection order, and collected last
# (tests/test_readme.py is) one of them would run alone at the end while the other worker idles.
LONGEST_MODULES = (
    'mux_trainer/test_learned.py', 'mux_trainer/test_dask_cluster.py', 'test_readme.py',
    'lightstage_bringup/test_web_health.py', 'lightstage_recording/test_demo_bag.py',
    'mux_classifier/test_inference_graph.py', 'lightstage_recording/test_record_replay_graph.py',
    'mux_trainer/test_cli_trainer.py',
)
TESTS = Path(__file__).resolve().parent


def _stale_slow_entries() -> list[str]:
    """Listed slow modules or tests that no longer exist: a moved or renamed test would
    otherwise fall back into `-m fast` without a word."""
    stale = [m for m in (*SLOW_MODULES, *LONGEST_MODULES) if not (TESTS / m).is_file()]
    for entry in SLOW_TESTS:
        module, name = entry.split('::')
        path = TESTS / module
        if not path.is_file() or not re.search(rf'^\s*def {re.escape(name)}\(', path.read_text(), re.M):
            stale.append(entry)
    return sorted(stale)


def pytest_configure(config):
    if stale := _stale_slow_entries():
        raise pytest.UsageError('tests/conftest.py lists slow tests that do not exist (moved or '
                                f'renamed? update SLOW_MODULES / SLOW_TESTS): {stale}')


@functools.lru_cache(maxsize=None)
def _module_declares_process(path) -> bool:
    return declares_process(path.read_text())


def _slow_module(path) -> bool:
    return path.relative_to(TESTS).as_posix() in SLOW_MODULES


def _slow(item) -> bool:
    return (_slow_module(item.path) or SLOW_FIXTURES & set(item.fixturenames)
            or f'{item.path.relative_to(TESTS).as_posix()}::{item.originalname}' in SLOW_TESTS)


def _starts_processes(item) -> bool:
    return bool(PROCESS_FIXTURES & set(item.fixturenames))


def pytest_ignore_collect(collection_path, config):
    """`-m fast` does not even import the modules it would run nothing of (their imports,
    rclpy's among them, cost seconds of the inner loop)."""
    if (config.option.markexpr == 'fast' and collection_path.name.startswith('test_')
            and (_module_declares_process(collection_path) or _slow_module(collection_path))):
        return True
    return None


def pytest_collection_modifyitems(config, items):
    """Markers by what a test does, so that none is forgotten: `process` for the tests of
    the firmware fixtures and `slow` (above; a module's own `pytestmark` declares `process`), and `fast`
    for every test that is neither `ros`, `process` nor `slow` (the inner loop: `-m fast`); the
    longest modules first (`LONGEST_MODULES`)."""
    for item in items:
        if _starts_processes(item):
            item.add_marker('process')
        if _slow(item):
            item.add_marker('slow')
        if not any(item.get_closest_marker(name) for name in NOT_FAST):
            item.add_marker('fast')
    rank = {m: i for i, m in enumerate(LONGEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.relative_to(TESTS).as_posix(), len(rank)))


@pytest.fixture(autouse=True)
def process_guard(request, monkeypatch):
    """A `fast` test starts no process (tests/helpers/markers.py): under the guard, a process
    start raises and fails the test, even where the code under test catches the error."""
    if request.node.get_closest_marker('fast') is None:
        yield None
        return
    guard = ProcessGuard(request.node.nodeid).install(monkeypatch)
    yield guard
    if guard.attempts:
        pytest.fail(f'{request.node.nodeid} is not marked `process` but started processes '
                    f'({", ".join(guard.attempts)}): add `pytestmark = pytest.mark.process` to its module')


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
def tiny_capture(tmp_path_factory):
    """2 classes (banana real/fake) x 4 poses at the classifier's 120 px: trains in seconds
    (the trainer node's goals in the graph tests)."""
    from lightstage_physics import synth
    out = tmp_path_factory.mktemp('capture') / 'c'
    synth.generate(out, image_size=120, n_samples_per_class=1, n_poses=4,
                   object_types=('banana',), n_jobs=1)
    return out


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


def _train_stage_artifact(stage_capture, tmp_path_factory, features, calibrate=False):
    from lightstage_physics.capture_format import load_capture
    from mux_trainer.baselines import FixedPatternClassifier
    from mux_trainer.search_params import Rendering, SplitScoring
    from helpers.suite import TRAIN_SITE_PATTERNS
    modelset = load_capture(stage_capture, downscale_to=120)
    model = FixedPatternClassifier(patterns=TRAIN_SITE_PATTERNS, seed=0,
                                   scoring=SplitScoring(n_repeats=10),
                                   rendering=Rendering(noise='sigma3', features=features)
                                   ).fit(modelset)
    path = tmp_path_factory.mktemp('artifact') / f'classifier_{features}.npz'
    artifact = model.to_artifact()
    if calibrate:
        from dataclasses import replace
        from mux_trainer.calibration import calibrate_pattern_model
        artifact = replace(artifact, confidence=calibrate_pattern_model(model))
    artifact.save(path)
    return path


@pytest.fixture(scope='session')
def stage_calibrated_artifact_path(stage_capture, tmp_path_factory):
    """The stage artifact with calibrated probabilities and its anytime rule
    (`mux_trainer.calibration`, as `lightstage train` fits them)."""
    return _train_stage_artifact(stage_capture, tmp_path_factory, 'hog_grid', calibrate=True)


@pytest.fixture(scope='session')
def stage_artifact(stage_artifact_path):
    from mux_classifier.artifact import TrainedArtifact
    return TrainedArtifact.load(stage_artifact_path)


@pytest.fixture
def small_modelset():
    """A small ModelSet (helpers.camera.make_modelset) for the physics and camera tests."""
    from helpers.camera import make_modelset
    return make_modelset()


@pytest.fixture(scope='session', params=[False, True], ids=['graded', 'on_off'])
def stage_learned_artifact_path(request, stage_capture, tmp_path_factory):
    """A learned artifact (4 exposures, graded or on/off levels, 3 steps: little learned, but
    a real one) trained on the stage capture the way `lightstage train --method learned` does."""
    from mux_trainer.training import train_from_capture
    path = tmp_path_factory.mktemp('learned') / f'learned_{request.param_index}.npz'
    train_from_capture(stage_capture, path, method='learned', max_images=4, steps=3,
                       binary=request.param, seed=0)
    return path
