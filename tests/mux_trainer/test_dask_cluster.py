"""`lightstage train --dask-scheduler` on a real Dask cluster of separate processes on loopback
(`dask scheduler` and two `dask worker`s, one thread each, no nanny so that a worker's PID is
the process that runs its tasks): the same result as the local run, also when a worker is
killed mid-column; a clear error when the scheduler cannot be reached or goes away."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.process

distributed = pytest.importorskip('distributed')

from mux_trainer.cli import train_main  # noqa: E402
from mux_trainer.cluster import ClusterUnavailable, DaskCluster, dask_cluster  # noqa: E402

LIGHTSTAGE = str(Path(sys.executable).parent / 'lightstage')
# small search on the suite's stage capture (4 classes) loaded at 60 px (HOG cells of 6 px: the
# cells of 120 px at 12), a quarter of the rendering: 2 columns, both kept
SEARCH = ['--repeats', '4', '--max-images', '2', '--image-size', '60', '--cell-px', '6',
          '--fixed-count', '--refine-top', '2', '--seed', '3', '--json', '--quiet']


@pytest.fixture(scope='module')
def local_result(stage_capture, tmp_path_factory):
    out = tmp_path_factory.mktemp('local') / 'local.npz'
    return _train_in_process(stage_capture, out, ['--jobs', '1'])


def _train_in_process(capture, out, extra):
    import contextlib
    import io
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert train_main([str(capture), '--out', str(out), *SEARCH, *extra]) == 0
    return json.loads(buffer.getvalue())


def _same_search(remote, local):
    assert remote['patterns'] == local['patterns']
    assert remote['accuracy_by_images'] == local['accuracy_by_images']  # exactly
    assert remote['best_n_images'] == local['best_n_images']


def test_train_on_a_cluster_gives_the_local_result(cluster, stage_capture, local_result, tmp_path):
    address, _ = cluster
    with distributed.Client(address, set_as_default=False) as watcher:
        watcher.get_task_stream()  # starts the scheduler's record of the tasks
        remote = _train_in_process(stage_capture, tmp_path / 'remote.npz',
                                   ['--dask-scheduler', address, '--jobs', '1'])
        stream = watcher.get_task_stream(count=100000)
    ran_on = {task['worker'] for task in stream if str(task['key']).startswith('score_chunk_with')}
    _same_search(remote, local_result)
    assert len(ran_on) == 2, stream  # both workers evaluated candidates


def test_a_worker_killed_mid_column_costs_only_its_tasks(cluster, stage_capture, local_result,
                                                         tmp_path):
    address, workers = cluster
    # the scheduler named by the environment variable, as a user's shell would set it
    env = dict(os.environ, LIGHTSTAGE_DASK_SCHEDULER=address)
    search = subprocess.Popen([LIGHTSTAGE, 'train', str(stage_capture), '--out',
                               str(tmp_path / 'killed.npz'), *SEARCH], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with distributed.Client(address, set_as_default=False) as watcher:
            victim = next(a for a, w in watcher.scheduler_info(n_workers=-1)['workers'].items()
                          if w['name'] == 'a')
            # wait (on the scheduler's state, not a sleep) until worker a runs a search task
            while not any(str(key).startswith('score_chunk_with')
                          for key in watcher.processing([victim]).get(victim, ())):
                assert search.poll() is None, search.communicate()
                time.sleep(0.01)
            workers['a'].send_signal(signal.SIGKILL)
            workers['a'].wait(timeout=30)
        out, err = search.communicate(timeout=600)
    finally:
        if search.poll() is None:
            search.kill()
    assert search.returncode == 0, err
    _same_search(json.loads(out), local_result)


def test_an_unreachable_scheduler_fails_quickly_naming_it(stage_capture, tmp_path, capsys):
    address = 'tcp://127.0.0.1:9'  # discard port: nothing listens on loopback
    with pytest.raises(SystemExit) as exit_info:
        train_main([str(stage_capture), '--out', str(tmp_path / 'x.npz'), *SEARCH,
                    '--dask-scheduler', address, '--dask-timeout', '2'])
    message = str(exit_info.value.code)
    assert message.startswith(f'lightstage train: the Dask scheduler {address} refused the '
                              'connection: nothing listens on port 9')
    assert not (tmp_path / 'x.npz').exists()


def test_an_unreachable_scheduler_from_the_command_line(stage_capture, tmp_path):
    run = subprocess.run([LIGHTSTAGE, 'train', str(stage_capture), '--out',
                          str(tmp_path / 'x.npz'), '--dask-scheduler', 'tcp://127.0.0.1:9',
                          '--dask-timeout', '2', *SEARCH], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode != 0
    assert 'tcp://127.0.0.1:9' in run.stderr and run.stdout == ''


def test_a_scheduler_that_goes_away_is_named(dask_scheduler, tiny_data):
    from mux_trainer.candidate_patterns import site_pattern_candidates
    from mux_trainer.evaluation import CandidateEvaluator
    address, scheduler = dask_scheduler  # no workers: tasks would wait forever
    ev = CandidateEvaluator(tiny_data, n_repeats=4, seed=1, chunk_size=10)
    ctx = ev.prepare_column(None)
    with pytest.raises(ClusterUnavailable, match=address.replace('.', r'\.')):
        with dask_cluster(address, timeout_s=2) as connected:
            assert isinstance(connected, DaskCluster)
            scheduler.kill()
            scheduler.wait(timeout=30)
            ev.score(ctx, site_pattern_candidates()[:, :20])


def test_bytes_broadcast_count_the_shared_state_once_per_worker(cluster, tiny_data):
    from mux_trainer.candidate_patterns import site_pattern_candidates
    from mux_trainer.cluster import shared_bytes
    from mux_trainer.evaluation import CandidateEvaluator
    address, _ = cluster
    ev = CandidateEvaluator(tiny_data, n_repeats=4, seed=1, chunk_size=10)
    W = site_pattern_candidates()[:, :40]
    local = ev.score(ev.prepare_column(W[:, [5]]), W)
    with distributed.Client(address, set_as_default=False) as other:
        memory_manager_was_running = other.amm.running()
    with dask_cluster(address) as remote:
        assert not remote.client.amm.running()  # it would drop the broadcast copies
        ctx = ev.prepare_column(W[:, [5]])
        scores = ev.score(ctx, W)  # 4 tasks
        ev.score(ctx, W[:, :3], chunk_size=1)  # 3 more: the context is not sent again
        assert remote.bytes_broadcast == 2 * (shared_bytes(tiny_data) + shared_bytes(ctx))
        # the scheduler's own accounting of what it holds, on how many workers
        futures = [future for _, future in remote._shared.values()]
        who_has = remote.client.who_has(futures)
        assert all(len(holders) == 2 for holders in who_has.values())
    with distributed.Client(address, set_as_default=False) as other:
        assert other.amm.running() == memory_manager_was_running  # restored
    np.testing.assert_array_equal(scores, local)


def test_eval_on_a_cluster_gives_the_local_result(cluster, stage_capture, capsys):
    from mux_trainer.cli import eval_main
    address, _ = cluster
    options = [str(stage_capture), '--methods', 'naive,greedy', '--repeats', '4',
               '--image-size', '60', '--cell-px', '6',
               '--max-images', '2', '--renders', '1', '--seed', '3', '--json', '--quiet']

    def evaluate(extra):
        assert eval_main([*options, *extra]) == 0
        doc = json.loads(capsys.readouterr().out)
        return {name: (m['patterns'], m['search_accuracy_by_images'], m['accuracy_by_images'])
                for name, m in doc['methods'].items()}
    assert evaluate(['--dask-scheduler', address]) == evaluate(['--jobs', '1'])
