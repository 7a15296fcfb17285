"""`lightstage train` / `lightstage eval` on a tiny capture folder."""
import json

import numpy as np
import pytest
from lightstage_camera.capture_format import write_capture
from mux_classifier.model import TrainedArtifact

from mux_trainer.cli import eval_main, train_main

TINY = ['--image-size', '24', '--cell-px', '6', '--block-cells', '4']


@pytest.fixture(scope='module')
def capture(tmp_path_factory):
    from trainer_helpers import make_modelset
    path = tmp_path_factory.mktemp('capture') / 'tiny'
    write_capture(path, make_modelset(n_poses=8))
    return path


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
                 'accuracy_vs_images.png', 'patterns.png'):
        assert (out_dir / name).stat().st_size > 0
    table = (out_dir / 'table1.csv').read_text().splitlines()
    assert table[0].startswith('noise,method,fruit0,fruit1,overall') and len(table) == 5


def test_eval_selects_methods_and_noises(capture, capsys):
    rc = eval_main([str(capture), '--repeats', '4', '--max-images', '1', '--renders', '1',
                    '--methods', 'naive,greedy_joint', '--noise', 'sigma1,sigma2', '--json',
                    '--quiet', *TINY])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc['methods']) == {'naive', 'greedy_joint'}
    assert doc['noise'] == 'sigma1' and set(doc['by_noise']) == {'sigma1', 'sigma2'}


def test_bad_input_fails_clearly(capture, tmp_path, capsys):
    with pytest.raises(SystemExit, match='no such capture folder'):
        train_main([str(tmp_path / 'missing'), '--out', str(tmp_path / 'a.npz')])
    with pytest.raises(SystemExit, match='unknown method'):
        eval_main([str(capture), '--methods', 'naive,magic', *TINY])
    with pytest.raises(SystemExit, match='unknown noise'):
        eval_main([str(capture), '--noise', 'sigma9', *TINY])
    with pytest.raises(SystemExit, match='--repeats must be >= 1'):
        eval_main([str(capture), '--repeats', '0', *TINY])
    with pytest.raises(SystemExit, match='--refine-top must be >= 0'):
        train_main([str(capture), '--out', str(tmp_path / 'a.npz'), '--refine-top', '-1', *TINY])
    with pytest.raises(SystemExit, match='cannot downscale 24x24 .* --image-size'):
        train_main([str(capture), '--out', str(tmp_path / 'a.npz'), '--quiet'])
