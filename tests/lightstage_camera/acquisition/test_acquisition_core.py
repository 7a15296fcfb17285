"""Model acquisition without ROS: plan, averaging, the exposure preview, the capture folder."""
from dataclasses import replace

import numpy as np
import pytest
import yaml

from helpers.acquisition import (averaged_capture_z, check_z, gaussian_regime, sim_grab,
                                 smooth_modelset)
from lightstage_camera import acquisition as acq
from lightstage_camera import capture_destination as dest
from lightstage_camera import rescue
from lightstage_camera.capture_settings import CaptureSettings
from lightstage_camera.sim_camera import SimCamera
from lightstage_physics import errors, output_files
from lightstage_physics.capture_format import load_capture
from lightstage_physics.errors import AcquisitionError
from lightstage_physics.noise import PAPER_CALIBRATION

EXPOSURE_US, GAIN_DB = 30000, 15.0


def test_single_led_plan_names_and_settings():
    p = acq.led_patterns(8)
    assert p.shape == (32, 32) and np.array_equal(p, np.eye(32))
    assert [acq.led_name(i) for i in (0, 1, 3, 4, 31)] == ['s0_red', 's0_green', 's0_nir',
                                                            's1_red', 's7_nir']
    assert dest.model_files()[:2] == ['s0_red.png', 's0_green.png']
    s = CaptureSettings(exposure_us=1000, frames=5)
    assert (s.n_leds, s.total_frames, s.max_level) == (32, 160, 1023)
    for bad, match in ((dict(exposure_us=0), 'exposure_us'), (dict(frames=0), 'frames'),
                       (dict(gain_db=float('nan')), 'gain_db'),
                       (dict(frames_per_request=33), 'frames_per_request'),
                       (dict(max_saturated_fraction=2.0), 'max_saturated_fraction')):
        with pytest.raises(ValueError, match=match):
            CaptureSettings(**bad)


def test_averager_counts_pixels_that_hit_the_maximum_in_any_frame():
    avg = acq.FrameAverager(1023)
    avg.add(np.array([[10.0, 1023.0]]))
    avg.add(np.array([[12.0, 1000.0]]))
    np.testing.assert_allclose(avg.mean(), [[11.0, 1011.5]])
    assert avg.saturated_pixels == 1
    with pytest.raises(ValueError, match='changed its image size'):
        avg.add(np.zeros((2, 2)))


def test_captured_model_matches_the_stored_model_within_the_noise_of_n_frames():
    """Averaging N frames of the simulated camera (dimmer 1: a single LED at full power *is*
    the model) gives the model within the exact frame distribution / N."""
    ms = smooth_modelset()
    cam = SimCamera(ms, sample=1, dimmer=1.0, seed=5)
    calls = []
    settings = CaptureSettings(exposure_us=EXPOSURE_US, gain_db=GAIN_DB, frames=6,
                                   frames_per_request=4)
    progress = []
    captured = acq.capture_model(sim_grab(cam, EXPOSURE_US, GAIN_DB, calls), settings,
                                 on_image=lambda *a: progress.append(a))
    assert captured.model.shape == (4, 8, 24, 32) and captured.model.dtype == np.float32
    # preview: 32 frames in requests of 4; then per LED 4 + 2 frames
    assert calls == [4] * 8 + [4, 2] * 32
    assert progress[0] == (1, 32, 's0_red') and progress[-1] == (32, 32, 's7_nir')
    assert captured.preview is not None and captured.preview.image_shape == (24, 32)
    assert captured.saturated_pixels == 0 and captured.saturation_warning() == ''
    noise = PAPER_CALIBRATION.at(GAIN_DB, EXPOSURE_US / 1000)
    check_z(averaged_capture_z(captured.model, ms.models[1], noise, 6),
            gaussian_regime(ms.models[1], noise))


def test_preview_refuses_a_clipping_led_before_the_long_capture():
    ms = smooth_modelset(dark=False)
    ms.models[0, 1, 2] = 1100.0  # s2_green saturates the whole image
    cam = SimCamera(ms, sample=0, dimmer=1.0, seed=1)
    calls = []
    settings = CaptureSettings(exposure_us=20000, frames=50)
    with pytest.raises(errors.ExposureError) as info:
        acq.capture_model(sim_grab(cam, 20000, GAIN_DB, calls), settings)
    message = str(info.value)
    assert 's2_green has 1e+02 % of its pixels' in message and 'exposure_us 20000' in message
    assert 'exposure_us 10000' in message  # clipped: at most half the exposure
    assert 'Nothing was captured' in message
    assert sum(calls) == 32  # only the preview
    # allowed: the capture runs and reports the clipped pixels
    allowed = replace(settings, frames=2, max_saturated_fraction=1.0)
    captured = acq.capture_model(sim_grab(cam, 20000, GAIN_DB), allowed)
    assert captured.saturated[2 * 4 + 1] == 24 * 32  # LED s2_green = site 2 * 4 + green
    assert captured.saturated_pixels == 24 * 32
    assert 's2_green (768 px)' in captured.saturation_warning()


def test_preview_suggests_an_exposure_from_the_brightest_led():
    check = acq.ExposureCheck(CaptureSettings(exposure_us=30000), np.array([100.0, 409.2]),
                              np.zeros(2), (4, 4))
    assert check.brightest_led == 1
    assert check.suggested_exposure_us() == int(30000 * 0.8 * 1023 / 409.2)


def test_cancel_between_images_raises_and_nothing_is_written(tmp_path):
    cam = SimCamera(smooth_modelset(), dimmer=1.0, seed=2)
    done = []
    with pytest.raises(errors.CaptureCancelled, match='s0_nir .*3 of 32.*nothing was written'):
        acq.capture_model(sim_grab(cam, 1000, GAIN_DB), CaptureSettings(exposure_us=1000, frames=2),
                          on_image=lambda *a: done.append(a), cancelled=lambda: len(done) >= 3)
    assert not any(tmp_path.iterdir())


def _captured(seed=0, frames=2, level=None, shape=(24, 32)):
    ms = smooth_modelset(shape=shape, seed=seed)
    cam = SimCamera(ms, dimmer=1.0, seed=seed)
    settings = CaptureSettings(exposure_us=1000, frames=frames)
    model = acq.capture_model(sim_grab(cam, 1000, GAIN_DB), settings, preview=False).model
    if level is not None:
        model = np.full_like(model, level)
    return settings, model


def _destination(root, pose='p00', settings=None, shape=(24, 32), overwrite=False, **kw):
    settings = settings or CaptureSettings(exposure_us=1000, frames=2)
    return dest.check_destination(root, 'banana-fake', 's0', pose,
                                 dest.capture_rig(settings, shape), overwrite=overwrite, **kw)


def test_write_creates_a_loadable_capture_folder_and_extends_it(tmp_path):
    root = tmp_path / 'new' / 'capture'
    settings, model = _captured()
    d = _destination(root, settings=settings)
    assert not d.rig_exists and not d.pose_exists
    pose_dir = dest.write_model(d, model)
    assert pose_dir == root / 'banana-fake' / 's0' / 'p00'
    assert sorted(p.name for p in pose_dir.iterdir()) == sorted(dest.model_files())
    rig = yaml.safe_load((root / 'rig.yaml').read_text())['camera']
    assert (rig['exposure_us'], rig['gain_db'], rig['frames_averaged']) == (1000.0, 15.0, 2)
    assert (rig['image_height'], rig['image_width']) == (24, 32)
    _, model2 = _captured(seed=1)
    dest.write_model(_destination(root, 'p01'), model2)
    ms = load_capture(root, cache=False)
    assert ms.sample_names == ['banana-fake/s0/p00', 'banana-fake/s0/p01']
    # stored MSB-aligned with 1/64 gray-level steps: the averages' precision survives
    np.testing.assert_allclose(ms.models[0], model, atol=0.5 / 64 + 1e-6)
    np.testing.assert_allclose(ms.models[1], model2, atol=0.5 / 64 + 1e-6)
    assert not (root / dest.STAGING_DIR).exists()


def test_an_existing_pose_is_refused_unless_overwrite_and_then_replaced(tmp_path):
    settings, model = _captured(level=100.0)
    dest.write_model(_destination(tmp_path, settings=settings), model)
    with pytest.raises(errors.DestinationError, match='p00 already exists.*overwrite'):
        _destination(tmp_path)
    d = _destination(tmp_path, overwrite=True)
    assert d.pose_exists
    # a refusal at write time too (the pose appeared during the capture)
    with pytest.raises(errors.DestinationError, match='already exists'):
        dest.write_model(d, model, overwrite=False)
    dest.write_model(d, np.full_like(model, 200.0), overwrite=True)
    ms = load_capture(tmp_path, cache=False)
    assert len(ms) == 1 and np.all(ms.models == 200.0)
    assert not (tmp_path / dest.STAGING_DIR).exists()


def test_overwrite_replaces_a_pose_folder_only(tmp_path):
    settings, model = _captured(level=100.0)
    dest.write_model(_destination(tmp_path, settings=settings), model)
    other = tmp_path / 'banana-fake' / 's0' / 'p01'
    other.mkdir()
    (other / 'thesis.tex').write_text('not an image of a pose')
    with pytest.raises(errors.DestinationError, match=r'p01 exists and is not a pose folder '
                                                     r'\(it holds thesis\.tex\); overwrite replaces only a pose'):
        _destination(tmp_path, 'p01', settings=settings, overwrite=True)
    assert (other / 'thesis.tex').exists()
    _destination(tmp_path, 'p00', settings=settings, overwrite=True)  # a pose: replaced


def test_a_written_pose_folder_has_the_umasks_mode_not_0700(tmp_path):
    """tempfile.mkdtemp made the staging folder, renamed into the pose folder, 0700: no one
    but the acquisition node's user could read the capture."""
    import os
    import stat
    old = os.umask(0o022)
    try:
        settings, model = _captured(level=100.0)
        pose = dest.write_model(_destination(tmp_path, settings=settings), model)
    finally:
        os.umask(old)
    assert stat.S_IMODE(pose.stat().st_mode) == 0o755
    assert stat.S_IMODE(pose.parent.stat().st_mode) == 0o755


def test_a_folder_whose_rig_disagrees_is_refused_naming_each_difference(tmp_path):
    settings, model = _captured(level=50.0)
    dest.write_model(_destination(tmp_path, settings=settings), model)
    other = CaptureSettings(exposure_us=30000, gain_db=12.0, frames=2)
    with pytest.raises(errors.DestinationError) as info:
        _destination(tmp_path, 'p01', settings=other, shape=(24, 33))
    message = str(info.value)
    assert 'camera.exposure_us: folder 1000.0, this capture 30000.0' in message
    assert 'camera.gain_db: folder 15.0, this capture 12.0' in message
    assert 'image_height x image_width: folder (24, 32), this capture (24, 33)' in message
    assert 'exposure_us 1000, gain_db 15, frames 2' in message  # what to do
    # the site geometry is compared only against an explicit rig file
    moved = dest.capture_rig(settings, (24, 32))
    moved.sites[0] = replace(moved.sites[0], x_mm=1.0)
    dest.check_destination(tmp_path, 'banana-fake', 's0', 'p01', moved)
    with pytest.raises(errors.DestinationError, match='site 0 position'):
        dest.check_destination(tmp_path, 'banana-fake', 's0', 'p01', moved, rig_from_file=True)


@pytest.mark.parametrize('label,sample,pose', [('../x', 's0', 'p0'), ('a/b', 's0', 'p0'),
                                               ('banana', '.hidden', 'p0'), ('x', 's0', '')])
def test_bad_names_are_refused(tmp_path, label, sample, pose):
    settings = CaptureSettings()
    with pytest.raises(errors.DestinationError, match='not a usable folder name'):
        dest.check_destination(tmp_path, label, sample, pose, dest.capture_rig(settings, (8, 8)))


def test_unusable_folders_are_refused_before_anything_is_captured(tmp_path):
    rig = dest.capture_rig(CaptureSettings(), (8, 8))
    (tmp_path / 'file').write_text('x')
    with pytest.raises(errors.DestinationError, match='not a folder'):
        dest.check_destination(tmp_path / 'file', 'a-b', 's0', 'p0', rig)
    with pytest.raises(errors.DestinationError, match='not a folder'):
        dest.check_destination(tmp_path / 'file' / 'sub', 'a-b', 's0', 'p0', rig)
    with pytest.raises(errors.DestinationError, match='cannot write into /proc'):
        dest.check_destination('/proc/lightstage-capture', 'a-b', 's0', 'p0', rig)
    (tmp_path / 'notes').mkdir()
    (tmp_path / 'notes' / 'readme.txt').write_text('x')
    with pytest.raises(errors.DestinationError, match='has no rig.yaml: it is not a capture folder'):
        dest.check_destination(tmp_path / 'notes', 'a-b', 's0', 'p0', rig)
    (tmp_path / 'broken').mkdir()
    (tmp_path / 'broken' / 'rig.yaml').write_text('sites: [')
    with pytest.raises(errors.DestinationError, match='rig.yaml does not load'):
        dest.check_destination(tmp_path / 'broken', 'a-b', 's0', 'p0', rig)
    with pytest.raises(errors.DestinationError, match='no output folder'):
        dest.check_destination('', 'a-b', 's0', 'p0', rig)


def test_a_write_that_fails_midway_leaves_nothing_behind(tmp_path, monkeypatch):
    settings, model = _captured(level=10.0)
    root = tmp_path / 'fresh'
    d = _destination(root, settings=settings)

    def failing_write(pose_dir, model, bit_depth, compress_level):
        (pose_dir / 's0_red.png').write_bytes(b'partial')
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(dest, 'write_pose', failing_write)
    with pytest.raises(errors.DestinationError, match='No space left.*nothing of this pose'):
        dest.write_model(d, model)
    assert not root.exists()  # the folder was created for this pose: gone again
    monkeypatch.undo()
    dest.write_model(_destination(tmp_path / 'kept', settings=settings), model)
    monkeypatch.setattr(dest, 'write_pose', failing_write)
    with pytest.raises(errors.DestinationError):
        dest.write_model(_destination(tmp_path / 'kept', 'p01', settings=settings), model)
    assert sorted(p.name for p in (tmp_path / 'kept').iterdir()) == ['banana-fake', 'rig.yaml']
    assert [p.name for p in (tmp_path / 'kept' / 'banana-fake' / 's0').iterdir()] == ['p00']


def test_classifier_and_acquisition_share_the_graph_frame_matching_and_stage_errors():
    from lightstage_graph import frames
    from lightstage_graph.errors import MissingImagesError, StageError
    from mux_classifier import inference
    assert inference.ImageMatcher is frames.ImageMatcher
    assert inference.image_from_buffer is frames.image_from_buffer
    assert inference.mono16_to_gray is frames.mono16_to_gray
    assert inference.MissingImagesError is MissingImagesError
    # one `except StageError` in each node catches the stage's failures and its own
    assert issubclass(AcquisitionError, StageError) and issubclass(inference.InferenceError, StageError)


def test_output_files_are_not_replaced_unless_asked(tmp_path):
    output_files.check_output_file(tmp_path / 'noise.yaml')
    (tmp_path / 'noise.yaml').write_text('x')
    with pytest.raises(errors.DestinationError, match='already exists'):
        output_files.check_output_file(tmp_path / 'noise.yaml')
    output_files.check_output_file(tmp_path / 'noise.yaml', overwrite=True)
    with pytest.raises(errors.DestinationError, match='is a folder'):
        output_files.check_output_file(tmp_path)


def test_goal_fields_fall_back_to_the_node_parameters():
    from types import SimpleNamespace

    from lightstage_camera.acquisition_node import _gain_or_default, _or_default
    assert _or_default(0, 30000) == 30000 and _or_default(5000, 30000) == 5000

    def goal(gain_db, gain_db_set):
        return SimpleNamespace(gain_db=gain_db, gain_db_set=gain_db_set)
    assert _gain_or_default(goal(float('nan'), False), 15.0) == 15.0
    assert _gain_or_default(goal(0.0, False), 15.0) == 15.0  # left out, as the ros2 CLI sends it
    assert _gain_or_default(goal(0.0, True), 15.0) == 0.0  # 0 dB is a gain the camera has
    assert _gain_or_default(goal(6.0, False), 15.0) == 6.0


def _failing_once(monkeypatch):
    """write_pose fails with a full disk until the returned list says otherwise."""
    real, fail = dest.write_pose, [True]

    def write_pose(pose_dir, model, bit_depth, compress_level):
        if fail[0]:
            raise OSError(28, 'No space left on device')
        return real(pose_dir, model, bit_depth, compress_level)

    monkeypatch.setattr(dest, 'write_pose', write_pose)
    return fail


def test_acquire_pose_checks_first_captures_and_writes(tmp_path):
    ms = smooth_modelset()
    cam = SimCamera(ms, sample=0, dimmer=1.0, seed=2)
    settings = CaptureSettings(exposure_us=EXPOSURE_US, gain_db=GAIN_DB, frames=2)
    stages, ready = [], []
    pose_dir, captured = acq.acquire_pose(
        sim_grab(cam, EXPOSURE_US, GAIN_DB), settings, tmp_path / 'cap', 'banana-fake', 's0',
        'p00', before_capture=lambda: ready.append(True),
        on_progress=lambda done, total, led, stage: stages.append((stage, done)))
    assert pose_dir == tmp_path / 'cap' / 'banana-fake' / 's0' / 'p00' and ready == [True]
    assert stages[0] == ('preview', 0) and stages[1] == ('capturing', 1)
    assert stages[-1] == ('writing', 32)
    loaded = load_capture(tmp_path / 'cap', cache=False)
    np.testing.assert_allclose(loaded.models[0], captured.model, atol=1 / 64)
    # a bad name is refused before anything is lit
    lit = []
    with pytest.raises(errors.DestinationError, match='pose'):
        acq.acquire_pose(sim_grab(cam, EXPOSURE_US, GAIN_DB, lit), settings, tmp_path / 'cap',
                         'banana-fake', 's0', '../p01')
    assert lit == []


def test_a_capture_that_cannot_be_written_is_kept_and_written_later(tmp_path, monkeypatch):
    monkeypatch.setenv('LIGHTSTAGE_RESCUE_DIR', str(tmp_path / 'rescue'))
    ms = smooth_modelset()
    cam = SimCamera(ms, sample=1, dimmer=1.0, seed=3)
    settings = CaptureSettings(exposure_us=EXPOSURE_US, gain_db=GAIN_DB, frames=2)
    fail = _failing_once(monkeypatch)
    with pytest.raises(errors.DestinationError) as err:
        acq.acquire_pose(sim_grab(cam, EXPOSURE_US, GAIN_DB), settings, tmp_path / 'cap',
                         'banana-fake', 's1', 'p00', preview=False)
    message = str(err.value)
    assert 'No space left' in message and '--from-rescued' in message
    (rescued,) = (tmp_path / 'rescue').glob('*.npz')
    assert str(rescued) in message
    assert not (tmp_path / 'cap' / 'banana-fake').exists()
    kept = rescue.load_rescued(rescued)
    assert (kept.label, kept.sample, kept.pose) == ('banana-fake', 's1', 'p00')
    assert kept.rig.exposure_us == EXPOSURE_US and kept.rig.frames_averaged == 2
    fail[0] = False
    pose_dir = rescue.write_rescued(rescued)
    assert pose_dir == tmp_path / 'cap' / 'banana-fake' / 's1' / 'p00' and not rescued.exists()
    loaded = load_capture(tmp_path / 'cap', cache=False)
    np.testing.assert_allclose(loaded.models[0], kept.model, atol=1 / 64)
    assert loaded.rig.exposure_us == EXPOSURE_US


def test_a_rescue_file_that_is_not_one_is_refused_clearly(tmp_path):
    bad = tmp_path / 'x.npz'
    np.savez(bad, model=np.zeros(3))
    with pytest.raises(errors.DestinationError, match='not a readable rescue file'):
        rescue.load_rescued(bad)
    with pytest.raises(errors.DestinationError, match='not a readable rescue file'):
        rescue.load_rescued(tmp_path / 'missing.npz')


def test_nothing_to_keep_the_rescue_in_says_so(tmp_path, monkeypatch):
    monkeypatch.setattr(output_files, 'rescue_dirs', lambda: [tmp_path / 'file' / 'below-a-file'])
    (tmp_path / 'file').write_text('not a folder')
    ms = smooth_modelset()
    settings = CaptureSettings(exposure_us=EXPOSURE_US, gain_db=GAIN_DB, frames=1)
    _failing_once(monkeypatch)
    with pytest.raises(errors.DestinationError, match='could not be kept anywhere else'):
        acq.acquire_pose(sim_grab(SimCamera(ms, dimmer=1.0), EXPOSURE_US, GAIN_DB), settings,
                         tmp_path / 'cap', 'banana-fake', 's0', 'p00', preview=False)


def test_the_capture_command_writes_a_rescued_pose_without_ros(tmp_path, capsys):
    from lightstage_bringup.acquisition_cli import capture_main
    ms = smooth_modelset()
    settings = CaptureSettings(exposure_us=EXPOSURE_US, gain_db=GAIN_DB, frames=1)
    captured = acq.capture_model(sim_grab(SimCamera(ms, dimmer=1.0), EXPOSURE_US, GAIN_DB),
                                 settings, preview=False)
    rescued = rescue.save_rescued(rescue.RescuedModel(
        tmp_path / 'meant', 'banana-real', 's3', 'p02',
        dest.capture_rig(settings, captured.model.shape[-2:]), captured.model))
    assert capture_main([str(tmp_path / 'other'), 'a/b/c', '--from-rescued', str(rescued)]) == 2
    assert 'give no TARGET' in capsys.readouterr().err
    assert capture_main([str(tmp_path / 'other'), '--from-rescued', str(rescued)]) == 0
    assert (tmp_path / 'other' / 'banana-real' / 's3' / 'p02').is_dir() and not rescued.exists()
    assert capture_main([str(tmp_path / 'other'), '--from-rescued', str(rescued)]) == 1
    assert 'not a readable rescue file' in capsys.readouterr().err
    assert capture_main([str(tmp_path / 'other')]) == 2
    assert 'at least one TARGET' in capsys.readouterr().err
