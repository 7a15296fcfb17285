"""`lightstage synth --placement` and the flat object families (coin, note, seal)."""
import math

import numpy as np
import pytest

from lightstage_physics import synth, synth_cli
from lightstage_physics.capture_format import load_capture
from lightstage_physics.rig import Rig

# Per-(colour, site) sums of two 32 px poses made by the generator before placement
# existed (seed 7, grape and banana): canonical placement must keep reproducing them.
BEFORE_PLACEMENT = {
    ("grape-fake", (7, 2, 0, 0, 0)): [
        [3212.403, 3200.696, 3075.196, 3180.351, 6011.884, 5894.701, 5825.636, 5862.708],
        [4119.494, 3995.604, 3793.549, 3921.691, 7394.566, 7229.454, 7110.1, 7166.233],
        [2527.277, 2588.004, 2501.405, 2594.601, 4916.968, 4842.559, 4804.428, 4825.972],
        [5137.822, 4992.263, 4755.619, 4900.224, 9030.235, 8951.703, 8805.386, 8881.017]],
    ("banana-real", (7, 3, 1, 0, 0)): [
        [7208.798, 7546.283, 8215.469, 7855.872, 12782.76, 13533.081, 13615.656, 13703.74],
        [7382.689, 7723.75, 8387.276, 7975.553, 13161.527, 13923.447, 13978.098, 14025.005],
        [2747.454, 2750.538, 2972.76, 2774.038, 5214.332, 5211.419, 5354.064, 5227.915],
        [7558.676, 7739.41, 8511.141, 8275.719, 13587.352, 14195.5, 14341.566, 14591.147]],
}


def test_canonical_placement_reproduces_the_generator_before_placement():
    rig = Rig.paper_default(32)
    jobs = {(j.class_name, j.seed): j for j in synth.plan(("grape", "banana"), 1, 1, 7)}
    for key, sums in BEFORE_PLACEMENT.items():
        for args in ((), ("canonical",)):
            model = synth.render_job(jobs[key], rig, 1.0, 0.1, *args)
            np.testing.assert_allclose(model.sum(axis=(2, 3)), sums, rtol=1e-6)
    # the pose draws themselves are exact (PCG64 + uniform)
    assert synth._pose_params((0, 0, 0, 0, 0, 1)) == {
        "cx": -2.163150379074068, "cy": 7.044581321543832,
        "rotation": 0.15101897559882504, "tilt": 0.1227537811727305}


def test_default_placement_writes_the_same_bytes_as_canonical(tmp_path):
    kw = dict(image_size=24, n_samples_per_class=1, n_poses=1, seed=3,
              object_types=("banana", "coin"), n_jobs=1)
    synth.generate(tmp_path / "default", **kw)
    synth.generate(tmp_path / "canonical", placement="canonical", **kw)
    synth.generate(tmp_path / "free", placement="free", **kw)
    files = sorted(p.relative_to(tmp_path / "default")
                   for p in (tmp_path / "default").rglob("*") if p.is_file())
    assert len(files) > 4
    for rel in files:
        assert (tmp_path / "default" / rel).read_bytes() == (tmp_path / "canonical" / rel).read_bytes()
    a = load_capture(tmp_path / "default", cache=False)
    b = load_capture(tmp_path / "free", cache=False)
    assert a.class_names == b.class_names and not np.array_equal(a.models, b.models)


def test_free_placement_covers_rotation_translation_and_scale():
    canonical = [synth._pose_params((1, 0, 0, 0, p, 1)) for p in range(300)]
    free = [synth._pose_params((1, 0, 0, 0, p, 1), "free") for p in range(300)]
    assert max(abs(p["rotation"]) for p in canonical) <= 0.6
    assert max(max(abs(p["cx"]), abs(p["cy"])) for p in canonical) <= 8
    rotations = np.array([p["rotation"] for p in free])
    assert rotations.min() < -0.8 * math.pi and rotations.max() > 0.8 * math.pi
    shifts = np.array([[p["cx"], p["cy"]] for p in free])
    assert np.abs(shifts).max() > 20 and np.abs(shifts).max() <= synth.FREE_SHIFT_MM
    scales = np.array([p["scale"] for p in free])
    assert synth.FREE_SCALE[0] <= scales.min() < 0.92 and 1.08 < scales.max() <= synth.FREE_SCALE[1]
    with pytest.raises(ValueError, match="placement"):
        synth._pose_params((1,), "upside_down")


def test_free_placement_moves_and_turns_the_object():
    rig = Rig.paper_default(64)
    job = synth.plan(("note",), 1, 4, 0)[0]
    centres = []
    for pose in range(4):
        job_p = synth.SampleJob(job.class_name, job.kind, job.variant, 0, pose, job.seed[:-1] + (pose,))
        image = synth.render_job(job_p, rig, 1.0, 0.0, "free").sum(axis=(0, 1))
        mask = image > 0.5 * image.max()
        rows, cols = np.nonzero(mask)
        centres.append((rows.mean(), cols.mean()))
    spread = np.ptp(np.array(centres), axis=0)
    assert spread.max() > 5  # pixels: the note lies in different places


def _real_and_fake(kind: str):
    """The same instance and pose rendered with the real and the fake material."""
    rig = Rig.paper_default(120)
    shape = synth._instance_params(kind, (0, 5, 0, 0))
    pose = synth._pose_params((0, 5, 0, 0, 0, 1), "free")
    mats = synth.MATERIALS[kind]
    real, fake = (synth.render_pose(kind, mats[v], shape, pose, rig, np.random.default_rng(2))
                  for v in ("real", "fake"))
    total = real.sum(axis=(0, 1))
    mask = total > 2 * total.min() + 50

    def diff(a, b):
        return np.linalg.norm((a - b)[mask]) / np.linalg.norm(b[mask])
    return real, fake, diff


@pytest.mark.parametrize("kind", ["coin", "seal"])
def test_a_printed_copy_matches_its_relief_original_under_every_led_and_only_then(kind):
    real, fake, diff = _real_and_fake(kind)
    # printed from a photograph under every LED: the same levels, pixel for pixel, in every
    # colour (float32 rounding apart)
    for c in range(4):
        assert diff(real[c].sum(axis=0), fake[c].sum(axis=0)) < 1e-5
    # one site's shading, shadows and glints tell them apart; a pattern lit on all sides
    # hides most of it
    single_sites = [diff(real[0, s], fake[0, s]) for s in range(8)]
    lower_ring = diff(real[0, :4].sum(axis=0), fake[0, :4].sum(axis=0))
    assert min(single_sites) > 1e-3 and max(single_sites) > 3 * lower_ring
    assert synth.MATERIALS[kind]["real"].emboss_mm == synth.flat_objects.PRINTED_RELIEF_MM[kind]


def test_a_flat_fake_is_a_copy_of_the_real_sample_with_its_number_and_a_fake_fruit_is_not(
        monkeypatch):
    jobs = synth.plan(("seal", "note", "grape"), 2, 1, 4)
    job = {(j.kind, j.variant, j.instance): j for j in jobs}
    # a copy lies on the stage its own way: its poses are drawn apart from the original's
    assert (synth._pose_params(job["seal", "fake", 1].seed + (1,), "free")
            != synth._pose_params(job["seal", "real", 1].seed + (1,), "free"))
    # laid the same way, a copy shows its original's design (the same levels under every
    # LED up to its paper's mottle), not another sample's
    pose = synth._pose_params((0, 5, 0, 0, 0, 1), "free")
    monkeypatch.setattr(synth, "_pose_params", lambda seed, placement="canonical": pose)
    rig = Rig.paper_default(64)

    def every_led(kind, variant, number):
        return synth.render_job(job[kind, variant, number], rig, 1.0, 0.0, "free").sum(axis=1)

    for kind in ("seal", "note"):
        copy, original, other = (every_led(kind, v, n)
                                 for v, n in (("fake", 1), ("real", 1), ("real", 0)))
        visible = slice(0, 3)  # the note's inks differ in NIR by design

        def diff(a, b):
            return np.linalg.norm(a[visible] - b[visible]) / np.linalg.norm(b[visible])
        assert diff(copy, original) < 0.3 * diff(copy, other)
    # fake fruit are fruit of their own (as before: the fruit data do not change)
    fruit = [synth._instance_params("grape", synth._instance_seed(job["grape", v, 1]))
             for v in ("fake", "real")]
    assert fruit[0]["tint"] != fruit[1]["tint"]


def test_note_inks_differ_only_in_nir():
    real, fake, diff = _real_and_fake("note")
    visible = [diff(real[c].sum(axis=0), fake[c].sum(axis=0)) for c in range(3)]
    nir = diff(real[3].sum(axis=0), fake[3].sum(axis=0))
    assert max(visible) < 0.08 and nir > 4 * max(visible)


def test_cli_takes_placement_and_flat_types(tmp_path, capsys):
    out = tmp_path / "flat"
    assert synth_cli.main([str(out), "--size", "24", "--samples", "1", "--poses", "1",
                       "--types", "coin,note,seal", "--placement", "free", "--jobs", "1"]) == 0
    assert "free placement" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == [
        "coin-fake", "coin-real", "note-fake", "note-real", "seal-fake", "seal-real"]
    with pytest.raises(SystemExit):
        synth_cli.main([str(tmp_path / "x"), "--placement", "sideways"])
    with pytest.raises(SystemExit):
        synth_cli.main([str(tmp_path / "y"), "--types", "coin,pebble"])
