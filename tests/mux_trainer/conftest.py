import pytest
from lightstage_physics.capture_format import write_capture

from helpers.trainer import make_search_data


@pytest.fixture(scope='module')
def tiny_data():
    """4 classes x 8 poses, 24 x 24 px, the rig's 8 sites."""
    return make_search_data()


@pytest.fixture(scope='module')
def tiny4_data():
    """The same kind of data with 4 sites only: 14 site patterns per column."""
    return make_search_data(n_sites=4, seed=1)


@pytest.fixture(scope='module')
def capture(tmp_path_factory):
    """A tiny capture folder (4 classes x 8 poses, 24 px) for the CLI tests."""
    from helpers.trainer import make_modelset
    path = tmp_path_factory.mktemp('capture') / 'tiny'
    write_capture(path, make_modelset(n_poses=8))
    return path


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if the capture is loaded: refused options and paths are refused before."""
    import mux_trainer.cli as cli

    def load(*_a, **_k):
        raise AssertionError('the capture was loaded although the command should have been '
                             'refused before')
    monkeypatch.setattr(cli, '_load', load)


@pytest.fixture
def dask_scheduler(request, tmp_path):
    """A `dask scheduler` process on 127.0.0.1 without workers, stopped at the end of the test:
    (address, process)."""
    from helpers.dask_cluster import start_scheduler
    return start_scheduler(request, tmp_path)


@pytest.fixture
def cluster(request, tmp_path, dask_scheduler):
    """`dask_scheduler` and two one-thread `dask worker` processes `a` and `b` that have joined
    it, stopped at the end of the test: (address, {name: worker process})."""
    from helpers.dask_cluster import start_workers
    address, _ = dask_scheduler
    return address, start_workers(request, tmp_path, address)
