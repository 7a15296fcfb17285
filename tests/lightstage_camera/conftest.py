import pytest

from camera_helpers import make_modelset


@pytest.fixture
def small_modelset():
    return make_modelset()
