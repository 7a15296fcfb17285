import pytest

from trainer_helpers import make_search_data


@pytest.fixture(scope='module')
def tiny_data():
    """4 classes x 8 poses, 24 x 24 px, the rig's 8 sites."""
    return make_search_data()


@pytest.fixture(scope='module')
def tiny4_data():
    """The same kind of data with 4 sites only: 14 site patterns per column."""
    return make_search_data(n_sites=4, seed=1)
