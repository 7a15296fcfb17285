"""The simulator as a standalone program: prints its pty and serves the protocol there."""
import os
import subprocess
import sys

import pytest
from lightstage_driver.stage import LightStage

from helpers.suite import REPO

pytestmark = pytest.mark.process

SRC = REPO / 'src' / 'lightstage_driver'


def test_standalone_simulator_prints_its_pty_and_answers():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), os.environ.get('PYTHONPATH', '')]))
    proc = subprocess.Popen([sys.executable, '-m', 'lightstage_driver.firmware_sim', '--pwm-bits', '12'],
                            stdout=subprocess.PIPE, text=True, env=env)
    try:
        lines = []
        while not any(line.startswith('PTY ') for line in lines):
            line = proc.stdout.readline()
            assert line, f'simulator exited without printing its pty: {lines}'
            lines.append(line)
        port = next(line for line in lines if line.startswith('PTY ')).split()[1]
        assert port.startswith('/dev/pts/')
        with LightStage(port) as stage:
            assert stage.identity.pwm_bits == 12 and stage.identity.name == 'lightstage-pysim'
            half = [0.5] * 32
            assert len(stage.apply([half], 100)) == 1
    finally:
        proc.terminate()
        assert proc.wait(5) == 0
