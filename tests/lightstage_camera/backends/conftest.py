"""Real-camera backends against the vendors' emulated cameras (no camera attached).

pylon's camera emulation (`PYLON_CAMEMU=N` emulated Basler cameras) is set here, before
any test of this directory creates pylon's transport layer; node processes started by the
tests inherit it. Every test that enumerates or opens a camera asks for `private_network`:
it refuses to run (fails, never skips) unless this process's network namespace has only
loopback, so that no discovery packet can leave the machine (scripts/run_tests.sh runs the
suite in such a namespace).
"""
import os

import numpy as np
import pytest

from helpers.emulated_cameras import write_served_images
from helpers.suite import network_interfaces

os.environ['PYLON_CAMEMU'] = '2'   # two emulated cameras: EMULATED_SERIALS


@pytest.fixture(scope='session')
def private_network():
    interfaces = network_interfaces()
    if interfaces != ['lo']:
        pytest.fail(f'this test enumerates cameras, which broadcasts discovery packets on every '
                    f'interface; it runs only in a private network namespace with loopback alone '
                    f'(here: {", ".join(interfaces)}). Run it through scripts/run_tests.sh (as root).')


@pytest.fixture
def served_images(tmp_path):
    """Three known 16-bit 48 x 64 images in a folder the emulated camera serves."""
    rng = np.random.default_rng(14)
    images = [rng.integers(0, 65536, (48, 64), dtype=np.uint16) for _ in range(3)]
    folder = tmp_path / 'served'
    write_served_images(folder, images)
    return folder, images
