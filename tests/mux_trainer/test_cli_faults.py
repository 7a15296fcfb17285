"""Faults of the train and eval CLI, the unequal pose counts, and the --jobs default.

Output paths that cannot be written are refused before any work; a path that stops taking
files during the run does not lose the result. The tests run as root, so "read-only" is
made real for root: /proc (no new files), an existing folder, a path under a regular file,
and `chattr +i` (immutable, refused even to root) where the file system supports it.
"""
import json
import os
import shlex
import shutil
import subprocess

import numpy as np
import pytest
from lightstage_physics.workers import usable_cores
from mux_classifier.artifact import TrainedArtifact

import mux_trainer.report as report
import mux_trainer.training as training
from mux_trainer.cli import eval_main, train_main

from helpers.trainer import TINY

pytestmark = pytest.mark.process
TRAIN = ['--repeats', '6', '--max-images', '2', '--fixed-count', *TINY]
EVAL = ['--no-answers', '--repeats', '4', '--max-images', '1', '--renders', '1', '--methods', 'naive,greedy',
        '--no-plots', *TINY]


def _immutable(path):
    """`chattr +i path` (root cannot create files in it either); skip where unsupported."""
    if shutil.which('chattr') is None:
        pytest.skip('chattr not available')
    done = subprocess.run(['chattr', '+i', str(path)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f'chattr +i not supported here: {done.stderr.strip()}')
    return path


def _mutable(path):
    subprocess.run(['chattr', '-i', str(path)], check=False, capture_output=True)


@pytest.fixture
def read_only_dir(tmp_path):
    path = tmp_path / 'ro'
    path.mkdir()
    _immutable(path)
    yield path
    _mutable(path)


# ---------------------------------------------------------------- item 3: refused up front
def test_train_out_in_a_read_only_folder_is_refused_before_training(capture, read_only_dir, no_work):
    with pytest.raises(SystemExit, match=rf'cannot write the artifact {read_only_dir}/x.npz: '
                                         rf'cannot write into {read_only_dir} .*writable folder'):
        train_main([str(capture), '--out', str(read_only_dir / 'x.npz'), *TRAIN])


def test_train_out_under_proc_is_refused_before_training(capture, no_work):
    with pytest.raises(SystemExit, match='cannot write the artifact /proc/a.npz: cannot write '
                                         'into /proc'):
        train_main([str(capture), '--out', '/proc/a.npz', *TRAIN])


def test_train_out_an_existing_folder_is_refused_before_training(capture, tmp_path, no_work):
    with pytest.raises(SystemExit, match=f'{tmp_path} is a folder; give a file name'):
        train_main([str(capture), '--out', str(tmp_path), *TRAIN])


def test_train_out_under_a_regular_file_is_refused_before_training(capture, tmp_path, no_work):
    (tmp_path / 'file').write_text('')
    with pytest.raises(SystemExit, match=f'{tmp_path}/file is not a folder'):
        train_main([str(capture), '--out', str(tmp_path / 'file' / 'x.npz'), *TRAIN])


@pytest.mark.parametrize('kind', ['read_only', 'proc', 'regular_file'])
def test_eval_out_that_takes_no_files_is_refused_before_evaluating(capture, tmp_path, no_work,
                                                                   kind):
    if kind == 'read_only':
        out = _immutable(tmp_path)
        expected = f'cannot write the results into {out}: cannot write into {out}'
    elif kind == 'proc':
        out = '/proc/results'
        expected = 'cannot write the results into /proc/results: cannot write into /proc'
    else:
        out = tmp_path / 'file'
        out.write_text('')
        expected = f'cannot write the results into {out}: {out} is not a folder'
    try:
        with pytest.raises(SystemExit, match=expected):
            eval_main([str(capture), '--out', str(out), *EVAL])
    finally:
        _mutable(tmp_path)


def test_the_trainer_core_refuses_the_path_before_loading(capture, tmp_path):
    """The trainer node's path (`train_from_capture`): the same check, a ValueError."""
    with pytest.raises(ValueError, match='is a folder'):
        training.train_from_capture(capture, tmp_path, repeats=4, max_images=1)


# ---------------------------------------------------------------- item 3: kept at the end
def _break_folder(folder, how):
    """The folder stops taking files during the run (after the start-up check)."""
    if how == 'read_only':
        _immutable(folder)
    else:  # replaced by a regular file: works for root without chattr
        shutil.rmtree(folder)
        folder.write_text('')


def _restore_folder(folder, how):
    if how == 'read_only':
        _mutable(folder)
    elif folder.is_file():
        folder.unlink()
        folder.mkdir()


@pytest.mark.parametrize('how', ['read_only', 'replaced_by_file'])
def test_train_keeps_the_artifact_when_the_folder_breaks_during_training(
        capture, tmp_path, rescue_dir, monkeypatch, capsys, how):
    folder = tmp_path / 'models'
    folder.mkdir()
    out = folder / 'x.npz'
    build = training.build_model

    def build_then_break(**options):
        model = build(**options)
        _break_folder(folder, how)
        return model

    monkeypatch.setattr(training, 'build_model', build_then_break)
    try:
        rc = train_main([str(capture), '--out', str(out), '--json', '--quiet', *TRAIN])
    finally:
        _restore_folder(folder, how)
    assert rc == 1
    captured = capsys.readouterr()
    doc = json.loads(captured.out)  # the result is printed all the same
    kept = doc['artifact']
    assert kept.startswith(str(rescue_dir)) and os.path.isfile(kept)
    assert f'could not write the artifact {out}' in captured.err
    assert f'the trained artifact is kept in {kept}: move it where you want it (mv {kept} {out})' \
        in captured.err
    assert not out.exists()
    # the kept file is the artifact: move it as told and it loads with the printed patterns
    shutil.move(kept, out)
    art = TrainedArtifact.load(out)
    np.testing.assert_array_equal(art.site_patterns, np.array(doc['patterns']))
    assert art.n_images == [4, 8]


@pytest.mark.parametrize('how', ['read_only', 'replaced_by_file'])
def test_eval_keeps_the_results_when_the_folder_breaks_during_the_evaluation(
        capture, tmp_path, rescue_dir, monkeypatch, capsys, how):
    out = tmp_path / 'eval'
    out.mkdir()
    run = report.run_evaluation

    def run_then_break(*args, **kwargs):
        results = run(*args, **kwargs)
        _break_folder(out, how)
        return results

    monkeypatch.setattr(report, 'run_evaluation', run_then_break)
    try:
        rc = eval_main([str(capture), '--out', str(out), '--quiet', *EVAL])
    finally:
        _restore_folder(out, how)
    assert rc == 1
    captured = capsys.readouterr()
    assert 'held-out accuracy' in captured.out and 'greedy' in captured.out  # printed
    assert f'could not write the results into {out}' in captured.err
    kept = captured.err.split('kept in ', 1)[1].split(':', 1)[0]
    assert kept.startswith(str(rescue_dir))
    doc = json.loads(open(kept).read())
    printed = doc['methods']['greedy']['accuracy']
    assert f'{100 * printed:6.2f} %' in captured.out
    # the command the message gives writes the outputs from the kept file, no new evaluation
    command = shlex.split(captured.err.split('`', 2)[1])
    assert command[:2] == ['lightstage', 'eval']
    shutil.rmtree(out, ignore_errors=True)
    assert eval_main(command[2:]) == 0
    assert json.loads((out / 'results.json').read_text()) == doc
    assert (out / 'table1.csv').read_text().count('\n') == 3  # header + 2 methods
    assert (out / 'patterns.png').stat().st_size > 0


def test_from_results_refuses_what_it_cannot_use(tmp_path, capsys):
    (tmp_path / 'bad.json').write_text('{"methods": 1}')
    with pytest.raises(SystemExit, match=r'bad.json is not a results.json of lightstage eval'):
        eval_main(['--from-results', str(tmp_path / 'bad.json'), '--out', str(tmp_path / 'o')])
    assert not (tmp_path / 'o').exists()
    with pytest.raises(SystemExit, match=r'cannot read .*missing.json as JSON \(No such file'):
        eval_main(['--from-results', str(tmp_path / 'missing.json'), '--out', str(tmp_path / 'o')])
    with pytest.raises(SystemExit):
        eval_main(['--from-results', str(tmp_path / 'bad.json')])  # no --out
    assert '--from-results FILE takes --out DIR' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        eval_main(['--repeats', '2'])  # neither a capture nor --from-results
    assert 'give CAPTURE_DIR' in capsys.readouterr().err


# ---------------------------------------------------------------- item 11: --jobs 0
@pytest.mark.parametrize('main', [train_main, eval_main], ids=['train', 'eval'])
def test_jobs_zero_names_the_flag(capture, tmp_path, capsys, main, no_work):
    argv = [str(capture), '--jobs', '0', *TINY]
    if main is train_main:
        argv += ['--out', str(tmp_path / 'a.npz')]
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert ('argument --jobs: must be a number of worker processes >= 1, or -1 for all '
            f'{usable_cores()} usable cores; got 0') in err
    assert 'has no meaning' not in err


@pytest.mark.parametrize('verb', ['synth', 'demo'])
def test_jobs_zero_names_the_flag_in_the_other_verbs(tmp_path, capsys, verb):
    from lightstage_bringup.cli import main
    with pytest.raises(SystemExit) as info:
        main([verb, '--jobs', '0'] + ([str(tmp_path / 'out')] if verb == 'synth' else []))
    assert info.value.code == 2
    assert 'argument --jobs: must be a number of worker processes >= 1' in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()


def test_the_cores_refuse_zero_workers_by_name(tiny_data):
    with pytest.raises(ValueError, match='n_jobs must be a number of worker processes >= 1'):
        training.build_model(n_jobs=0)
    with pytest.raises(ValueError, match='n_jobs must be a number of worker processes >= 1'):
        report.evaluate_noise_setting(None, 'sigma3', n_jobs=0)


def test_trainer_node_refuses_zero_workers():
    """The node's n_jobs range is 1..256 (a range holding -1 would hold 0): 0 is refused when
    set, not when a goal arrives."""
    import rclpy
    from rclpy.parameter import Parameter

    from mux_trainer.trainer_node import TrainerNode
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = TrainerNode(node_name='trainer_faults_jobs', context=context)
        try:
            assert node.get_parameter('n_jobs').value == min(usable_cores(), 256)
            result, = node.set_parameters([Parameter('n_jobs', value=0)])
            assert not result.successful
            assert node.get_parameter('n_jobs').value == min(usable_cores(), 256)
            result, = node.set_parameters([Parameter('n_jobs', value=1)])
            assert result.successful
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


# ---------------------------------------------------------------- --jobs default
def test_jobs_default_is_the_usable_cores(capture, tmp_path, monkeypatch):
    seen = {}

    def record(modelset, out_path, **options):
        seen.update(options)
        raise ValueError('stop here')

    monkeypatch.setattr(training, 'train_modelset', record)
    with pytest.raises(SystemExit, match='stop here'):
        train_main([str(capture), '--out', str(tmp_path / 'a.npz'), '--quiet', *TINY])
    assert seen['n_jobs'] == usable_cores() == len(os.sched_getaffinity(0))


def test_results_do_not_depend_on_jobs(capture, tmp_path, capsys):
    docs, arts = [], []
    for jobs in ('1', '2'):
        out = tmp_path / f'j{jobs}.npz'
        assert train_main([str(capture), '--out', str(out), '--jobs', jobs, '--json', '--quiet',
                           *TRAIN]) == 0
        doc = json.loads(capsys.readouterr().out)
        docs.append({k: v for k, v in doc.items() if k not in ('artifact', 'train_seconds')})
        arts.append(TrainedArtifact.load(out))
    assert docs[0] == docs[1]
    np.testing.assert_array_equal(arts[0].led_patterns, arts[1].led_patterns)
    for a, b in zip(arts[0].stages, arts[1].stages):
        np.testing.assert_array_equal(a.coef, b.coef)
        np.testing.assert_array_equal(a.intercept, b.intercept)
    evals = []
    for jobs in ('1', '2'):
        assert eval_main([str(capture), '--jobs', jobs, '--json', '--quiet', *EVAL]) == 0
        doc = json.loads(capsys.readouterr().out)
        evals.append({name: (m['accuracy'], m['accuracy_by_images'], m['patterns'])
                      for name, m in doc['methods'].items()})
    assert evals[0] == evals[1]


# ---------------------------------------------------------------- also seen: unequal poses
def test_classes_with_different_numbers_of_poses_are_refused(capture, tmp_path):
    uneven = tmp_path / 'uneven'
    shutil.copytree(capture, uneven, ignore=shutil.ignore_patterns('.cache'))
    label = sorted(p.name for p in uneven.iterdir() if p.is_dir())[1]
    for pose in ('p06', 'p07'):
        shutil.rmtree(uneven / label / 's0' / pose)
    expected = (rf'{uneven}: classes have different numbers of poses \(6 pose\(s\): {label}; '
                r'8 pose\(s\): .*every class needs the same number of poses '
                r'\(docs/CAPTURE_FORMAT.md\): capture the missing poses')
    with pytest.raises(SystemExit, match=expected):
        train_main([str(uneven), '--out', str(tmp_path / 'a.npz'), '--quiet', *TRAIN])
    with pytest.raises(SystemExit, match=expected):
        eval_main([str(uneven), '--quiet', *EVAL])
    assert not (tmp_path / 'a.npz').exists()
