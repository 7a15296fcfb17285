"""`lightstage train` / `lightstage eval` on a tiny capture folder."""
import json

import numpy as np
import pytest
from lightstage_physics.capture_format import write_capture
from lightstage_physics.rig import DEFAULT_DIMMER
from mux_classifier.artifact import TrainedArtifact

from mux_trainer.cli import eval_main, train_main

from helpers.trainer import TINY


def test_train_json_and_artifact(capture, tmp_path, capsys):
    out = tmp_path / 'model.npz'
    rc = train_main([str(capture), '--out', str(out), '--repeats', '8', '--max-images', '2',
                     '--fixed-count', '--json', '--quiet', *TINY])
    assert rc == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)  # stdout is exactly one JSON document
    assert doc['method'] == 'greedy' and doc['mode'] == 'per_colour'
    assert set(doc['accuracy_by_images']) == {'1', '2'}
    assert np.array(doc['patterns']).shape == (8, 2)
    art = TrainedArtifact.load(out)
    assert art.n_images == [4, 8]
    np.testing.assert_array_equal(art.site_patterns, np.array(doc['patterns']))
    assert art.class_names == doc['class_names']
    assert art.noise['name'] == 'sigma3'
    assert art.dimmer == DEFAULT_DIMMER and art.dimmer_recorded  # what the training rendered with


@pytest.mark.parametrize('method,mode,n_images', [('snr_optimal', 'per_colour', [4, 8]),
                                                  ('naive', 'naive', [1]),
                                                  ('greedy', 'joint', [1, 2])])
def test_train_other_methods(capture, tmp_path, capsys, method, mode, n_images):
    out = tmp_path / f'{method}.npz'
    extra = ['--mode', 'joint', '--fixed-count'] if mode == 'joint' else []
    rc = train_main([str(capture), '--out', str(out), '--method', method, '--repeats', '4',
                     '--max-images', '2', '--noise', 'sigma1', '--json', '--quiet', *extra, *TINY])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['method'] == method
    art = TrainedArtifact.load(out)
    assert art.mode == mode and art.n_images == n_images


def test_eval_json_shape_and_outputs(capture, tmp_path, capsys):
    out_dir = tmp_path / 'eval'
    rc = eval_main([str(capture), '--repeats', '6', '--max-images', '2', '--renders', '2',
                    '--json', '--out', str(out_dir), *TINY])
    assert rc == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert 'held-out accuracy' in captured.err  # progress goes to stderr
    assert set(doc['methods']) == {'naive', 'naive_bow', 'snr_optimal', 'greedy'}
    for name, m in doc['methods'].items():
        assert 0.0 <= m['accuracy'] <= 1.0
        assert set(m['accuracy_by_type']) == {'fruit0', 'fruit1'}
        assert m['accuracy_by_images'] and all(0 <= v <= 1 for v in m['accuracy_by_images'].values())
    assert set(doc['methods']['greedy']['accuracy_by_images']) == {'1', '2'}
    for name in ('results.json', 'table1.csv', 'accuracy_vs_images.csv',
                 'accuracy_vs_images.png', 'accuracy_vs_exposures.png', 'patterns.png'):
        assert (out_dir / name).stat().st_size > 0
    table = (out_dir / 'table1.csv').read_text().splitlines()
    assert table[0].startswith('noise,method,fruit0,fruit1,overall') and len(table) == 5
    # the calibrated answers of every pattern method (naive + BoW has no calibration)
    assert 'answers' not in doc['methods']['naive_bow']
    for name in ('naive', 'snr_optimal', 'greedy'):
        a = doc['methods'][name]['answers']
        assert a['budget_images'] == doc['methods'][name]['n_exposures']
        assert a['full_accuracy'] == pytest.approx(doc['methods'][name]['accuracy'])
        assert 1 <= a['anytime_mean_images'] <= a['budget_images']
        bins = a['reliability']['full']
        assert sum(b['answers'] for b in bins) == a['answers']
        assert a['full_calibration_error'] == pytest.approx(
            sum(b['answers'] * abs(b['accuracy'] - b['confidence']) for b in bins) / a['answers'])
        assert a['coverage_curve'][-1]['coverage'] == 1.0  # of the anytime answers
        assert a['coverage_curve'][-1]['accuracy'] == pytest.approx(a['anytime_accuracy'])
        u = a['unknown']  # each of the two fruit left out of the novelty model in turn
        assert set(u['by_left_out_type']) == {'fruit0', 'fruit1'}
        assert 0 <= u['flagged'] <= 1 and 0 <= u['false_alarms'] <= 1
    answers = (out_dir / 'answers.csv').read_text().splitlines()
    assert answers[0].startswith('noise,method,budget_exposures') and len(answers) == 4
    assert (out_dir / 'answers.png').stat().st_size > 0


def test_eval_selects_methods_and_noises(capture, capsys):
    rc = eval_main([str(capture), '--repeats', '4', '--max-images', '1', '--renders', '1',
                    '--methods', 'naive,greedy_joint', '--noise', 'sigma1,sigma2', '--json',
                    '--joint-max-images', '3', '--quiet', '--no-answers', *TINY])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc['methods']) == {'naive', 'greedy_joint'}
    assert doc['noise'] == 'sigma1' and set(doc['by_noise']) == {'sigma1', 'sigma2'}
    # the joint mode's own column budget (one exposure per column)
    joint = doc['methods']['greedy_joint']
    assert set(joint['accuracy_by_images']) == {'1', '2', '3'}
    assert joint['images_per_pattern'] == 1 and doc['settings']['joint_max_images'] == 3
    assert doc['settings']['dimmer'] == DEFAULT_DIMMER


def test_eval_and_train_with_feature_extractors(capture, tmp_path, capsys):
    """--features runs every method once per extractor; methods stay the first's,
    by_features holds each; train writes an artifact on the chosen extractor."""
    out_dir = tmp_path / 'eval'
    rc = eval_main([str(capture), '--repeats', '4', '--max-images', '1', '--renders', '1',
                    '--methods', 'naive,naive_bow,greedy', '--features', 'hog_grid,intensity_stats',
                    '--json', '--quiet', '--no-answers', '--out', str(out_dir), *TINY])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['features'] == 'hog_grid' and doc['settings']['features'] == ['hog_grid', 'intensity_stats']
    assert set(doc['by_features']) == {'hog_grid', 'intensity_stats'}
    assert doc['by_features']['hog_grid']['methods'] == doc['methods']
    other = doc['by_features']['intensity_stats']['methods']
    assert set(other) == {'naive', 'naive_bow', 'greedy'}
    assert other['naive_bow'] == doc['methods']['naive_bow']  # its own features: run once
    table = (out_dir / 'table1_features.csv').read_text().splitlines()
    assert table[0].startswith('features,noise,method') and len(table) == 1 + 2 * 3
    out = tmp_path / 'stats.npz'
    rc = train_main([str(capture), '--out', str(out), '--repeats', '4', '--max-images', '1',
                     '--features', 'intensity_stats', '--json', '--quiet', *TINY])
    assert rc == 0
    assert json.loads(capsys.readouterr().out)['features'] == 'intensity_stats'
    assert TrainedArtifact.load(out).features == 'intensity_stats'
    with pytest.raises(SystemExit, match="unknown feature extractor 'sift'"):
        eval_main([str(capture), '--features', 'hog_grid,sift', *TINY])
    with pytest.raises(SystemExit, match='learns from images'):
        train_main([str(capture), '--out', str(tmp_path / 'b.npz'), '--features', 'bow', *TINY])
    with pytest.raises(SystemExit, match='--features takes one name'):
        train_main([str(capture), '--out', str(tmp_path / 'b.npz'), '--features',
                    'hog_grid,intensity_stats', *TINY])


def test_eval_holds_out_whole_physical_samples(capture, tmp_path, capsys):
    import dataclasses
    from helpers.trainer import make_modelset
    base = make_modelset(n_poses=8)
    path = tmp_path / 'four_samples'
    write_capture(path, dataclasses.replace(base, instance=base.pose_index // 2,
                                            sample_names=[''] * len(base.labels)))  # s<i>/p<j>
    args = ['--repeats', '4', '--max-images', '1', '--renders', '1', '--methods', 'naive',
            '--holdout-by', 'instances', *TINY]
    assert eval_main([str(path), *args]) == 0
    assert 'held-out accuracy (test samples [' in capsys.readouterr().out
    assert eval_main([str(path), '--json', '--quiet', *args]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['settings']['holdout_by'] == 'instances'
    assert len(doc['by_noise']['sigma3']['test_instances']) == 1
    # one physical sample per class cannot be split that way: a clear error
    with pytest.raises(SystemExit, match='at least 2 physical samples'):
        eval_main([str(capture), *args])


def test_bad_input_fails_clearly(capture, tmp_path, capsys):
    with pytest.raises(SystemExit, match='no such capture folder'):
        train_main([str(tmp_path / 'missing'), '--out', str(tmp_path / 'a.npz')])
    with pytest.raises(SystemExit, match='unknown method'):
        eval_main([str(capture), '--methods', 'naive,magic', *TINY])
    with pytest.raises(SystemExit, match='unknown noise'):
        eval_main([str(capture), '--noise', 'sigma9', *TINY])
    with pytest.raises(SystemExit, match='--repeats must be >= 1'):
        eval_main([str(capture), '--repeats', '0', *TINY])
    with pytest.raises(SystemExit, match='--joint-max-images must be >= 1'):
        eval_main([str(capture), '--joint-max-images', '0', *TINY])
    with pytest.raises(SystemExit, match='--refine-top must be >= 0'):
        train_main([str(capture), '--out', str(tmp_path / 'a.npz'), '--refine-top', '-1', *TINY])
    with pytest.raises(SystemExit, match='cannot downscale 24x24 .* --image-size'):
        train_main([str(capture), '--out', str(tmp_path / 'a.npz'), '--quiet'])


def test_train_with_a_calibrated_noise_file(capture, tmp_path, capsys):
    """A noise file of `lightstage calibrate` trains exactly like a preset with the same
    numbers, NOISE.yaml@GAIN:EXPOSURE generalizes it, and the artifact carries the camera
    setting the classifier node then asks the stage for."""
    from lightstage_physics.noise import PAPER_CALIBRATION, preset, save_noise_file
    sigma3 = preset('sigma3')

    def train(noise, name):
        out = tmp_path / name
        assert train_main([str(capture), '--out', str(out), '--repeats', '6', '--max-images', '1',
                           '--fixed-count', '--noise', noise, '--json', '--quiet', *TINY]) == 0
        return json.loads(capsys.readouterr().out), TrainedArtifact.load(out)

    doc, art = train(str(save_noise_file(tmp_path / 'sigma3.yaml', sigma3)), 'file.npz')
    ref_doc, ref_art = train('sigma3', 'preset.npz')
    assert doc['accuracy_by_images'] == ref_doc['accuracy_by_images']
    np.testing.assert_array_equal(art.site_patterns, ref_art.site_patterns)
    for key in ('sigma_p2', 'sigma_r2', 'gain_db', 'exposure_ms'):
        assert art.noise[key] == ref_art.noise[key]
    assert art.noise['name'].endswith('sigma3.yaml')
    # the paper's 15 dB / 30 ms fit generalized to Sigma3's setting: Sigma3 to the rounding
    # of that fit (docs/PHYSICS.md), at Sigma3's gain and exposure
    paper = save_noise_file(tmp_path / 'paper.yaml', PAPER_CALIBRATION)
    _, art = train(f'{paper}@17.5:22.5', 'paper.npz')
    assert art.noise['name'].endswith('paper.yaml@17.5:22.5')
    assert (art.noise['gain_db'], art.noise['exposure_ms']) == (17.5, 22.5)
    assert art.noise['sigma_p2'] == pytest.approx(sigma3.sigma_p2, rel=0.01)
    assert art.noise['sigma_r2'] == pytest.approx(sigma3.sigma_r2, rel=1e-3)
    _, art = train(str(paper), 'own.npz')
    assert (art.noise['gain_db'], art.noise['exposure_ms'], art.noise['sigma_p2']) == (15, 30, 0.7)


def test_bad_noise_settings_fail_clearly(capture, tmp_path):
    out = str(tmp_path / 'a.npz')
    with pytest.raises(SystemExit, match="unknown noise setting 'sigma9'.*lightstage calibrate"):
        train_main([str(capture), '--out', out, '--noise', 'sigma9', '--quiet', *TINY])
    with pytest.raises(SystemExit, match='missing.yaml: cannot read the noise file'):
        train_main([str(capture), '--out', out, '--noise', str(tmp_path / 'missing.yaml'),
                    '--quiet', *TINY])
    (tmp_path / 'other.yaml').write_text('kind: something_else\n')
    with pytest.raises(SystemExit, match='not a noise calibration file'):
        eval_main([str(capture), '--noise', f'sigma3,{tmp_path / "other.yaml"}', '--quiet', *TINY])
    with pytest.raises(SystemExit, match=r"after the @ give GAIN_DB:EXPOSURE_MS.*not '17\.5'"):
        train_main([str(capture), '--out', out, '--noise', 'noise.yaml@17.5', '--quiet', *TINY])
    assert not (tmp_path / 'a.npz').exists()


def test_eval_count_rule_reports_what_each_rule_keeps(capture, capsys):
    rc = eval_main([str(capture), '--repeats', '6', '--max-images', '3', '--renders', '1',
                    '--methods', 'greedy,snr_optimal', '--count-rule', 'one_se', '--json',
                    '--no-answers', *TINY])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['settings']['count_rule'] == 'one_se'
    for m in doc['methods'].values():
        rules = m['by_count_rule']
        assert m['count_rule'] == 'one_se' and set(rules) == {'max', 'one_se'}
        assert m['n_images'] == rules['one_se']['n_images'] <= rules['max']['n_images']
        for r in rules.values():  # each rule's held-out accuracy is that count's
            assert r['accuracy'] == m['accuracy_by_images'][str(r['n_images'])]
        assert set(m['search_se_by_images']) == set(m['search_accuracy_by_images'])
    with pytest.raises(SystemExit):
        eval_main([str(capture), '--count-rule', 'median', *TINY])


def test_train_says_what_it_kept_in_exposures_and_columns(capture, tmp_path, capsys):
    """One word for one thing: exposures are images taken, pattern columns what a per-colour
    column is (4 exposures: R, G, B, NIR); the features named; no Python dicts."""
    rc = train_main([str(capture), '--out', str(tmp_path / 'n.npz'), '--method', 'naive',
                     '--repeats', '4', *TINY])
    assert rc == 0
    text = capsys.readouterr().out
    assert "{'" not in text and 'image count' not in text
    assert 'naive: 1 pattern column of joint patterns, 1 exposure per column; features ' \
           'hog_grid' in text
    assert 'best: the first 1 exposure, by the inner accuracy' in text
    assert 'inner accuracy by exposures: 1 exposure ' in text
    assert 'inner estimate ' in text and 'objects trained on' in text


def test_eval_rows_name_their_exposures_columns_and_own_features():
    from mux_trainer.cli import method_row, train_text
    types = {'accuracy_by_type': {'banana': 0.9}}
    snr = dict(types, accuracy=0.845, n_images=4, images_per_pattern=4, n_exposures=16,
               features='hog_grid', mode='per_colour')
    learned = dict(types, accuracy=1.0, n_images=4, images_per_pattern=1, n_exposures=4,
                   features='intensity_stats', cross_image_stats=True, mode='learned',
                   levels='on/off', inner_estimate={'accuracy': 0.97, 'held_out': 'physical samples'})
    bow = dict(types, accuracy=0.5, n_images=1, images_per_pattern=1, features='bow_dense_hog')
    assert ' 84.50 %  at 16 exposures (4 pattern columns x 4), features hog_grid  [' \
        in method_row('snr_optimal', snr)
    assert '100.00 %  at 4 exposures, features intensity_stats + cross-image statistics, ' \
           'on/off levels, inner estimate 97.0 % by physical samples  [' in method_row('learned', learned)
    assert 'at 1 exposure, features bag of words on dense HOG' in method_row('naive_bow', bow)
    doc = {'method': 'greedy', 'mode': 'per_colour', 'patterns': [[1, 0]] * 8,
           'images_per_pattern': 4, 'features': 'hog_grid', 'best_n_images': 2,
           'accuracy_by_images': {'1': 0.8, '2': 0.9}}
    text = train_text(doc)
    assert 'greedy: 2 pattern columns of per-colour patterns, 4 exposures per column ' \
           '(R, G, B, NIR); features hog_grid' in text
    assert 'best: the first 8 exposures (2 pattern columns x 4)' in text
    assert 'inner accuracy by exposures: 4 exposures 80.0 %, 8 exposures 90.0 %' in text
