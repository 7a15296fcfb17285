import pytest

from helpers.camera import make_modelset


@pytest.fixture
def small_modelset():
    return make_modelset()
