import numpy as np
import pytest
from PIL import Image

from lightstage_physics import fruit_render, synth, synth_cli
from lightstage_physics.calibration_target import simulate_calibration_frames
from lightstage_physics.camera_plots import plot_noise_characteristic, plot_relit_sample
from lightstage_physics.capture_format import load_capture
from lightstage_physics.noise import PRESETS, NoiseModel
from lightstage_physics.noise_fit import fit_noise_model, noise_characteristic


@pytest.fixture(scope="module")
def tiny_synth(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    synth.generate(root / "a", image_size=32, n_samples_per_class=2, n_poses=1, seed=3,
                   object_types=("banana", "orange"), n_jobs=1)
    return root


def test_synth_writes_a_valid_capture(tiny_synth):
    ms = load_capture(tiny_synth / "a", cache=False)
    assert ms.class_names == ["banana-fake", "banana-real", "orange-fake", "orange-real"]
    assert ms.models.shape == (8, 4, 8, 32, 32)
    assert set(ms.object_type) == {"banana", "orange"}
    np.testing.assert_array_equal(ms.instance, np.tile([0, 1], 4))
    np.testing.assert_array_equal(ms.pose_index, np.tile([0, 1], 4))
    # objects are brighter than the floor, nothing saturates in a single-LED image
    assert ms.models.max() < 1023 and ms.models[:, :, :, 16, 16].mean() > 3 * ms.models[:, :, :, 0, 0].mean()


def test_synth_is_deterministic(tiny_synth, tmp_path):
    synth.generate(tmp_path / "b", image_size=32, n_samples_per_class=2, n_poses=1, seed=3,
                   object_types=("banana", "orange"), n_jobs=2)
    a, b = load_capture(tiny_synth / "a", cache=False), load_capture(tmp_path / "b", cache=False)
    np.testing.assert_array_equal(a.models, b.models)
    synth.generate(tmp_path / "c", image_size=32, n_samples_per_class=2, n_poses=1, seed=4,
                   object_types=("banana",), n_jobs=1)
    c = load_capture(tmp_path / "c", cache=False)
    assert not np.array_equal(c.models, a.models[:4])


def test_shadow_falls_away_from_the_light():
    z = np.zeros((40, 40))
    z[18:22, 18:22] = 30.0  # a post in the middle
    vis = fruit_render._shadow(z, azimuth=0.0, tan_elevation=1.0, px=1.0)  # light toward +x
    assert vis[20, 10] < 0.1  # behind the post (towards -x) is dark
    assert vis[20, 30] == pytest.approx(1.0)  # in front is lit
    assert vis[5, 10] == pytest.approx(1.0)


def test_fake_and_real_differ_but_match_under_all_leds():
    rig = synth.Rig.paper_default(64)
    jobs = synth.plan(["orange"], 1, 1, 0)
    fake, real = (synth.render_job(j, rig, 1.0, 0.0) for j in jobs)
    # identical materials when the differences are switched off
    same = synth.render_job(jobs[0], rig, 0.0, 0.0)
    real_same_pose = synth.render_job(synth.SampleJob("orange-real", "orange", "real", 0, 0,
                                                      jobs[0].seed[:2] + (0,) + jobs[0].seed[3:]),
                                      rig, 1.0, 0.0)
    np.testing.assert_allclose(same, real_same_pose, rtol=1e-5, atol=1e-4)
    assert fake.shape == (4, 8, 64, 64)
    fake_strength1 = synth.render_job(jobs[0], rig, 1.0, 0.0)
    assert np.abs(fake_strength1 - real_same_pose).max() > 5.0  # same pose, other material
    assert abs(fake.sum() / real.sum() - 1) < 0.25


def test_synth_cli(tmp_path, capsys):
    assert synth_cli.main([str(tmp_path / "d"), "--size", "24", "--poses", "1", "--samples", "1",
                       "--types", "grape", "--jobs", "1"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert len(load_capture(tmp_path / "d", cache=False)) == 2
    with pytest.raises(SystemExit):
        synth_cli.main([str(tmp_path / "e"), "--types", "kiwi"])
    args = [str(tmp_path / "d"), "--size", "24", "--poses", "1", "--samples", "1",
            "--types", "grape", "--jobs", "1", "--quiet"]
    assert synth_cli.main(args) == 2  # refuses to write into a non-empty folder
    assert "not empty" in capsys.readouterr().err
    assert synth_cli.main(args + ["--force"]) == 0


def test_plots_write_pngs(tiny_synth, tmp_path):
    frames = simulate_calibration_frames(NoiseModel(), n_levels=4, n_frames=20,
                                         rng=np.random.default_rng(0))
    fit = fit_noise_model(frames)
    out = plot_noise_characteristic(tmp_path / "noise.png", noise_characteristic(frames), fit,
                                    {k: fit.at(m.gain_db, m.exposure_ms) for k, m in PRESETS.items()})
    assert Image.open(out).size[0] > 300
    ms = load_capture(tiny_synth / "a", cache=False)
    out = plot_relit_sample(tmp_path / "relit.png", ms, 0, np.eye(8)[:, [0, 4]], PRESETS["sigma3"])
    assert Image.open(out).size[0] > 200
