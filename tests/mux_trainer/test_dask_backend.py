"""Candidate evaluation through joblib's Dask backend on a local loopback cluster."""
import numpy as np
import pytest

pytestmark = pytest.mark.process

distributed = pytest.importorskip('distributed')

from mux_trainer.candidate_patterns import site_pattern_candidates  # noqa: E402
from mux_trainer.evaluation import CandidateEvaluator  # noqa: E402
from mux_trainer.greedy import GreedyPatternSelector  # noqa: E402
from mux_trainer.search_params import Execution, SplitScoring  # noqa: E402


def test_dask_backend_gives_the_same_scores_and_patterns(tiny_data):
    import joblib
    W = site_pattern_candidates()[:, :40]
    ev = CandidateEvaluator(tiny_data, n_repeats=8, seed=1, chunk_size=10)
    ctx = ev.prepare_column(W[:, [5]])
    local = ev.score(ctx, W)
    local_sel = GreedyPatternSelector(n_patterns=1, seed=1,
                                      scoring=SplitScoring(n_repeats=8)).fit(tiny_data)
    # TCP on loopback (not the in-process transport), so tasks and data are serialised
    with distributed.LocalCluster(host='127.0.0.1', protocol='tcp', n_workers=2,
                                  threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        assert cluster.scheduler_address.startswith('tcp://127.0.0.1:')
        with joblib.parallel_backend('dask'), distributed.get_task_stream(client) as stream:
            ev_dask = CandidateEvaluator(tiny_data, n_repeats=8, seed=1, chunk_size=10, n_jobs=-1)
            remote = ev_dask.score(ev_dask.prepare_column(W[:, [5]]), W)
            sel = GreedyPatternSelector(n_patterns=1, seed=1, scoring=SplitScoring(n_repeats=8),
                                        execution=Execution(n_jobs=-1)).fit(tiny_data)
        # the candidate chunks really ran on the cluster's workers
        assert len(stream.data) >= 2
    np.testing.assert_array_equal(local, remote)
    np.testing.assert_array_equal(local_sel.patterns_, sel.patterns_)


def test_a_worker_measures_the_search_data_by_its_arrays():
    # A Dask worker unpickles the scattered SearchData and measures it with dask's sizeof
    # before it ever imports the evaluation module: the size must come with the class.
    import subprocess
    import sys
    code = (
        'import pickle, sys\n'
        'import numpy as np\n'
        'from mux_trainer.rendering import SearchData\n'
        'data = SearchData(basis=np.zeros((8, 4, 10, 144), np.float32), labels=np.zeros(10),\n'
        '                  pose_index=np.arange(10), class_names=["a"], image_shape=(12, 12))\n'
        'blob = pickle.dumps(data)\n'
        'from dask.sizeof import sizeof\n'
        'print("mux_trainer.evaluation" in sys.modules, sizeof(pickle.loads(blob)))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == 'False'  # the scenario: evaluation not imported
    assert int(out[1]) >= 8 * 4 * 10 * 144 * 4  # the basis alone


def test_a_column_context_is_measured_by_its_arrays():
    from dask.sizeof import sizeof
    from mux_trainer.evaluation import ColumnContext
    z = np.zeros((4, 10, 144), np.float32)
    ctx = ColumnContext('per_colour', 0, z, None, np.zeros((10, 10)), [np.zeros(10, bool)],
                        None, 2)
    assert sizeof(ctx) >= z.nbytes + 10 * 10 * 8 + 10
