"""Procedural object families (lightstage_physics.families) and `lightstage synth --family`."""
from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest
from scipy import stats

from lightstage_physics import families
from lightstage_physics.capture_format import load_capture
from lightstage_physics.synth import CHANNEL_POWER
from lightstage_physics.synth_cli import main as synth_main


def test_a_family_seed_draws_the_same_family_and_seeds_draw_many_kinds_and_cues():
    assert families.draw_family(5) == families.draw_family(5)
    drawn = [families.draw_family(s) for s in range(40)]
    assert len({f.kind for f in drawn}) >= 5
    assert len({c for f in drawn for c in f.cues}) == len(families.CUES)
    assert all(1 <= len(f.cues) <= families.MAX_CUES for f in drawn)


def test_the_classes_are_one_material_at_strength_zero_and_apart_by_the_strength():
    for seed in range(10):
        family = families.draw_family(seed)
        a, b = families.class_materials(family, 0.0)
        assert a == b
        a, b = families.class_materials(family, 0.5)
        assert a != b


def test_albedo_cues_leave_what_all_leds_see_unchanged():
    # the power-weighted mean albedo is the same for both classes: the all-LED image does
    # not get brighter or darker with the class
    checked = 0
    for seed in range(60):
        family = families.draw_family(seed)
        if not {'albedo', 'nir'} & set(family.cues):
            continue
        d = np.asarray(family.delta['albedo'])
        assert abs(np.dot(d, CHANNEL_POWER)) < 1e-9
        assert np.abs(d).max() > 0.01
        checked += 1
    assert checked >= 10


def test_samples_of_both_classes_are_drawn_from_one_distribution():
    # at strength 0 nothing but the seed tells a class-a sample from a class-b one: the
    # per-sample size, tint, gain and material jitter have the same distribution
    family = families.draw_family(2)
    material = families.class_materials(family, 0.0)[0]

    def summary(c):
        rows = []
        for s in range(150):
            d = families.sample_draw(family, c, s, material)
            rows.append([d['shape']['scale'], d['gain'], *d['shape']['tint'],
                         *d['material'].albedo, d['material'].relief_mm])
        return np.array(rows)

    a, b = summary(0), summary(1)
    assert a.std(axis=0).min() > 0   # samples do vary
    for j in range(a.shape[1]):
        assert stats.ks_2samp(a[:, j], b[:, j]).pvalue > 0.001, j


def test_samples_of_one_class_differ_and_poses_of_one_sample_differ():
    family = families.draw_family(7)
    from lightstage_physics.synth import capture_rig
    rig = capture_rig(24)
    p00 = families.render_family_pose(family, 0, 0, 0, 1.0, rig)
    p01 = families.render_family_pose(family, 0, 0, 1, 1.0, rig)
    p10 = families.render_family_pose(family, 0, 1, 0, 1.0, rig)
    assert p00.shape == (4, 8, 24, 24)
    assert np.array_equal(p00, families.render_family_pose(family, 0, 0, 0, 1.0, rig))
    assert not np.array_equal(p00, p01)
    assert not np.array_equal(p00, p10)
    g0 = families.sample_draw(family, 0, 0, family.base)['gain']
    g1 = families.sample_draw(family, 0, 1, family.base)['gain']
    assert g0 != g1


@pytest.mark.process  # the CLI's joblib run starts loky's resource tracker, even with --jobs 1
def test_synth_family_writes_a_loadable_capture_with_its_description(tmp_path):
    out = tmp_path / 'fam'
    assert synth_main([str(out), '--family', '3', '--strength', '0.7', '--samples', '2',
                       '--poses', '2', '--size', '24', '--jobs', '1', '--quiet']) == 0
    ms = load_capture(out)
    assert ms.class_names == list(families.CLASS_NAMES)
    assert len(ms) == 2 * 2 * 2
    assert sorted(set(ms.instance.tolist())) == [0, 1]
    assert ms.object_types == ['family']
    described = json.loads((out / 'family.json').read_text())
    family = families.draw_family(3)
    assert described['kind'] == family.kind and described['cues'] == list(family.cues)
    assert described['materials']['family-b'] == json.loads(json.dumps(
        asdict(families.class_materials(family, 0.7)[1])))
    again = tmp_path / 'again'
    assert synth_main([str(again), '--family', '3', '--strength', '0.7', '--samples', '2',
                       '--poses', '2', '--size', '24', '--jobs', '2', '--quiet']) == 0
    assert np.array_equal(load_capture(again).models, ms.models)


@pytest.mark.parametrize('argv, message', [
    (['--family', '1', '--strength', '-1'], 'strength must be'),
    (['--family', '1', '--sample-spread', '2'], 'sample_spread must be'),
])
def test_synth_family_refuses_bad_settings_and_writes_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / 'fam'
    assert synth_main([str(out), '--size', '24', '--quiet'] + argv) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


def test_sample_spread_needs_a_family(tmp_path):
    with pytest.raises(SystemExit):
        synth_main([str(tmp_path / 'x'), '--sample-spread', '0.1'])
