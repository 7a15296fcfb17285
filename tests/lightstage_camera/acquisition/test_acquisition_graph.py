"""End to end on the simulated stage: driver (Python firmware simulator), sim camera and the
acquisition node as processes; model capture and noise calibration through the graph.

The camera runs with dimmer 1.0: a single LED at full power then shows exactly the stored
model (the 0.45 dimmer is a rendering convention for multiplexed patterns, not physics), so
the stored model is the ground truth of the capture.
"""
import json
import math

import numpy as np
import pytest
import yaml
from lightstage_bringup.supervisor import Supervisor

from helpers.acquisition import StageGraph, averaged_capture_z, check_z, cli, gaussian_regime
from lightstage_camera.capture_destination import STAGING_DIR
from lightstage_physics.calibration_target import write_calibration_target
from lightstage_physics.capture_format import load_capture
from lightstage_physics.noise import PAPER_CALIBRATION, SETTINGS, load_noise_file
from lightstage_camera.sim_camera import frame_moments
from helpers.suite import fresh_domain_id, lightstage_command, write_params

pytestmark = [pytest.mark.ros, pytest.mark.process]

SAMPLE = 'banana-real/s0/p00'
EXPOSURE_US, GAIN_DB = 5000, 15.0  # short exposures keep the test fast; noise follows them
QUANTIZATION = 1.0 / 12.0  # rounding to whole gray levels adds this to a frame's variance


@pytest.fixture(scope='module')
def stage(tmp_path_factory):
    """The stage's capture folder (1 banana of each variant, 48 px) and a calibration target."""
    from lightstage_physics import synth
    root = tmp_path_factory.mktemp('stage')
    fruit = synth.generate(root / 'fruit', image_size=48, n_samples_per_class=1, n_poses=1,
                           object_types=('banana',), n_jobs=1)
    target = write_calibration_target(root / 'target', shape=(48, 64), dimmer=1.0)
    return fruit, target


@pytest.fixture(scope='module')
def graph(stage, tmp_path_factory):
    fruit, _ = stage
    domain_id = fresh_domain_id()
    params = write_params(tmp_path_factory.mktemp('graph') / 'params.yaml', {
        'camera': {'capture_dir': str(fruit), 'sample': SAMPLE, 'dimmer': 1.0, 'seed': 7},
        'acquisition': {'exposure_us': EXPOSURE_US, 'gain_db': GAIN_DB, 'frames_averaged': 2},
    })
    client = StageGraph(domain_id)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            client.start(supervisor, ['driver', 'camera', 'acquisition'], params)
            yield client
    finally:
        client.close()


def capture(client, out, pose, frames=0, overwrite=False, cancel_when=None, **goal):
    from lightstage_interfaces.action import CaptureModel
    g = CaptureModel.Goal(output_dir=str(out), label='banana-real', sample='s0', pose=pose,
                          frames_averaged=frames, gain_db=math.nan, overwrite=overwrite, **goal)
    return client.action(CaptureModel, '/lightstage/capture_model', g, cancel_when=cancel_when)


def test_captured_models_match_the_stored_one_and_averaging_follows_1_over_sqrt_n(
        graph, stage, tmp_path):
    from action_msgs.msg import GoalStatus
    fruit, _ = stage
    stored = load_capture(fruit, cache=False)
    truth = stored.models[stored.sample_names.index(SAMPLE)].astype(np.float64)
    # N = 2 through the CLI (node defaults: 5 ms, 15 dB, 2 frames), N = 8 through the action;
    # two folders: every pose of a folder has the folder's frame count (rig.yaml)
    p = cli('capture', str(tmp_path / 'n2'), 'banana-real/s0/n2', '--json',
            domain_id=graph.domain_id)
    assert p.returncode == 0, p.stderr + p.stdout
    (answer,) = json.loads(p.stdout)
    assert answer['success'] and answer['images_captured'] == 32, answer
    assert answer['saturated_pixels'] == 0
    status, result, feedback = capture(graph, tmp_path / 'n8', 'n8', frames=8)
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert result.model_dir == str(tmp_path / 'n8' / 'banana-real' / 's0' / 'n8')
    done = [f.images_done for f in feedback if f.stage == 'capturing']
    assert done == list(range(1, 33)) and feedback[-1].stage == 'writing'
    assert [f.current_led for f in feedback if f.stage == 'capturing'][:2] == ['s0_red', 's0_green']

    captured = []
    for n in (2, 8):
        ms = load_capture(tmp_path / f'n{n}', cache=False)
        assert ms.sample_names == [f'banana-real/s0/n{n}']
        assert (ms.rig.exposure_us, ms.rig.gain_db, ms.rig.frames_averaged) == \
            (EXPOSURE_US, GAIN_DB, n)
        captured.append(ms.models[0])
    noise = PAPER_CALIBRATION.at(GAIN_DB, EXPOSURE_US / 1000)  # the sim camera's noise: auto
    for model, n in zip(captured, (2, 8)):
        # every pixel within what averaging n frames of this camera predicts (most single-LED
        # pixels are dark: clipping at 0 is part of that prediction, `frame_moments`)
        check_z(averaged_capture_z(model, truth, noise, n), gaussian_regime(truth, noise))

    # averaging 4x more frames halves the RMS error: its mean square falls as 1/N. Measured
    # against the expected capture on every pixel, and against the stored model itself on the
    # pixels no frame clips (on dark pixels the stored model and the expected capture differ
    # by the camera's clipping at 0, which no averaging removes).
    mean, var = frame_moments(truth, noise.variance(truth))
    step2 = (1 / 64) ** 2 / 12  # 16-bit storage rounding
    clear = gaussian_regime(truth, noise, k=6)
    assert clear.sum() > 1000
    for reference, where in ((mean, np.ones_like(clear)), (truth, clear)):
        ms = []
        for model in captured:
            d2 = (model.astype(np.float64)[where] - reference[where]) ** 2
            ms.append((d2.mean(), d2.std() / math.sqrt(d2.size)))
        predicted = np.mean(var[where] / 8 + step2) / np.mean(var[where] / 2 + step2)
        assert predicted == pytest.approx(0.25, rel=1e-3)
        ratio = ms[1][0] / ms[0][0]
        ratio_sd = ratio * math.hypot(ms[0][1] / ms[0][0], ms[1][1] / ms[1][0])
        assert abs(ratio - predicted) < 4.5 * ratio_sd, (ratio, predicted, ratio_sd)


def test_an_existing_pose_or_another_setting_is_refused_before_anything_is_lit(graph, tmp_path):
    from action_msgs.msg import GoalStatus
    status, result, _ = capture(graph, tmp_path, 'p00', frames=1)
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    before = len(graph.illumination)
    status, result, feedback = capture(graph, tmp_path, 'p00', frames=1)
    assert status == GoalStatus.STATUS_ABORTED
    assert 'p00 already exists' in result.message and 'overwrite' in result.message
    status, result, _ = capture(graph, tmp_path, 'p01', frames=3)
    assert status == GoalStatus.STATUS_ABORTED
    assert 'camera.frames_averaged: folder 1, this capture 3' in result.message
    graph.spin_for(0.3)
    assert len(graph.illumination) == before and feedback == []  # nothing was lit
    status, result, _ = capture(graph, tmp_path, 'p00', frames=1, overwrite=True)
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert len(load_capture(tmp_path, cache=False)) == 1


def test_cancel_between_images_leaves_no_pose(graph, tmp_path):
    from action_msgs.msg import GoalStatus
    status, result, feedback = capture(graph, tmp_path, 'p00', frames=2,
                                       cancel_when=lambda f: f.images_done >= 3)
    assert status == GoalStatus.STATUS_CANCELED, result.message
    assert 'nothing was written' in result.message
    assert 3 <= max(f.images_done for f in feedback) < 32
    assert not list(tmp_path.iterdir())  # no pose, no rig.yaml, no staging folder
    # the stage is free again
    status, result, _ = capture(graph, tmp_path, 'p00', frames=1)
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert not (tmp_path / STAGING_DIR).exists()


def test_calibrating_the_simulated_stage_recovers_the_camera_noise(graph, stage, tmp_path):
    """Calibrate at 15 dB / 10 ms, 6 levels x 40 frames of a 48 x 64 target: the fit must be
    within 4 standard errors (from the frames and pixels used, `fit_uncertainty`, checked
    against many simulated calibrations in test_calibration_coverage) of the camera's configured noise,
    the paper's 0.7 / 66 fit generalized to 10 ms (plus the 1/12 of rounding); and so must
    its generalization to Sigma1..3, whose errors scale with the same factors."""
    fruit, target = stage
    noise_file, plot = tmp_path / 'noise.yaml', tmp_path / 'noise.png'
    p = cli('calibrate', str(noise_file), '--plot', str(plot), '--exposure-us', '10000',
            '--gain-db', '15', '--frames', '40', '--levels', '6', '--json',
            '--camera-param', f'capture_dir={target}', '--camera-param', 'sample=0',
            domain_id=graph.domain_id)
    try:
        assert p.returncode == 0, p.stderr + p.stdout
        r = json.loads(p.stdout)
        assert r['success'] and r['output_path'] == str(noise_file), r
        truth = PAPER_CALIBRATION.at(GAIN_DB, 10.0)
        se_p, se_r = r['sigma_p2_stderr'], r['sigma_r2_stderr']
        assert 0 < se_p < 0.02 * truth.sigma_p2 and 0 < se_r < 0.02 * truth.sigma_r2
        assert abs(r['sigma_p2'] - truth.sigma_p2) < 4 * se_p, r
        assert abs(r['sigma_r2'] - (truth.sigma_r2 + QUANTIZATION)) < 4 * se_r, r
        fit = load_noise_file(noise_file)
        assert (fit.sigma_p2, fit.sigma_r2, fit.exposure_ms) == (r['sigma_p2'], r['sigma_r2'], 10.0)
        for name, (g, e) in SETTINGS.items():
            got, want = fit.at(g, e), truth.at(g, e)
            p_scale = want.sigma_p2 / truth.sigma_p2
            r_scale = want.sigma_r2 / truth.sigma_r2
            assert abs(got.sigma_p2 - want.sigma_p2) < 4 * se_p * p_scale, name
            assert abs(got.sigma_r2 - want.sigma_r2 - QUANTIZATION * r_scale) < 4 * se_r * r_scale
        assert yaml.safe_load(noise_file.read_text())['measured']['leds_lit'][-1] == 32
        assert plot.read_bytes()[:4] == b'\x89PNG'
        # the sim camera takes the file; a file that is not one is refused with the reason
        assert graph.set_parameters('camera', noise_file=str(noise_file)).successful
        bad = graph.set_parameters('camera', noise_file=str(plot))
        assert not bad.successful and 'noise' in bad.reason
        # the file is read when it is named, not again when another setting changes
        moved = tmp_path / 'moved.yaml'
        noise_file.rename(moved)
        assert graph.set_parameters('camera', dimmer=1.0).successful
        moved.rename(noise_file)
        # existing outputs are not replaced unless asked; a plot format that does not exist is
        # refused before anything is lit
        again = cli('calibrate', str(noise_file), '--frames', '3', '--levels', '2',
                    domain_id=graph.domain_id)
        assert again.returncode == 1 and 'already exists' in again.stderr
        # too few frames for an unbiased fit: refused with the reason
        again = cli('calibrate', str(tmp_path / 'new.yaml'), '--frames', '2', '--levels', '2',
                    domain_id=graph.domain_id)
        assert again.returncode == 1 and 'at least 3 frames per level' in again.stderr
        again = cli('calibrate', str(tmp_path / 'new.yaml'), '--plot', str(tmp_path / 'n.txt'),
                    domain_id=graph.domain_id)
        assert again.returncode == 1 and 'should end in one of .png' in again.stderr
    finally:
        assert graph.set_parameters('camera', capture_dir=str(fruit), sample=SAMPLE,
                                    noise_file='').successful


def test_missing_driver_camera_and_images_are_reported(stage, tmp_path):
    """The acquisition node alone, then with a driver, then with a camera that images nothing
    (no capture folder): each goal aborts saying what is missing; nothing is written."""
    from action_msgs.msg import GoalStatus
    domain_id = fresh_domain_id()
    p = cli('capture', str(tmp_path / 'x'), 'a-b/s0/p0', '--wait-s', '0.5', domain_id=domain_id)
    assert p.returncode == 3 and '/lightstage/capture_model is not available' in p.stderr
    params = write_params(tmp_path / 'params.yaml', {
        'acquisition': {'timeout_s': 1.0, 'exposure_us': 1000, 'frames_averaged': 1},
        'camera': {'capture_dir': ''}})
    client = StageGraph(domain_id)
    out = tmp_path / 'out'

    def abort_message(until: str, *before: str) -> str:
        """Send goals until the abort message names `until`; a node started after the
        acquisition node is discovered a few seconds late, and until then the goals abort
        with an earlier problem, one of `before` (the deadline only guards against a hang)."""
        import time
        deadline = time.monotonic() + 60
        while True:
            status, result, _ = capture(client, out, 'p00')
            assert status == GoalStatus.STATUS_ABORTED, result.message
            if until in result.message:
                return result.message
            assert any(b in result.message for b in before), result.message
            assert time.monotonic() < deadline, result.message

    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            client.start(supervisor, ['acquisition'], params)
            no_driver = 'driver\'s service /lightstage/apply_patterns is not available'
            abort_message(no_driver)
            client.start(supervisor, ['driver'], params)
            no_camera = 'no camera is publishing camera/image_raw'
            abort_message(no_camera, no_driver)
            client.start(supervisor, ['camera'], params)
            # the camera has no capture folder: it says so for each trigger (camera/frame_lost);
            # until the camera and its notices are matched, the images just do not arrive
            message = abort_message('lost by the camera', no_camera, 'images did not arrive within')
            assert 'trigger sequence' in message and 'camera not ready: no capture folder' in message
            assert not out.exists()
            p = cli('capture', str(out), 'a-b/s0/p0', domain_id=domain_id)
            assert p.returncode == 1 and 'aborted' in p.stderr and 'no capture folder' in p.stderr
    finally:
        client.close()


def test_ctrl_c_in_the_cli_cancels_the_capture_and_leaves_no_pose(graph, tmp_path):
    """SIGINT to `lightstage capture` once the stage is visibly busy (triggers seen on
    /illumination): the CLI cancels the goal, exits 130, and the folder stays empty."""
    import signal
    import subprocess
    import time
    before = len(graph.illumination)
    proc = subprocess.Popen(lightstage_command('capture', str(tmp_path / 'out'), 'banana-real/s0/p00',
                                               '--frames', '16', '--domain-id', str(graph.domain_id)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while len(graph.illumination) < before + 64:  # past the preview, into the capture
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, 'the capture did not start'
            graph.spin_for(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert 'cancelling the goal' in err
    assert not (tmp_path / 'out').exists()
