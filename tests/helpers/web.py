"""Shared by the tests of `lightstage web` and `lightstage view`: a CLI server process that
prints its address on its first line, started beside a graph and stopped with Ctrl-C."""
from __future__ import annotations

import contextlib
import re
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from lightstage_graph.ros_env import ros_environment

from helpers.suite import lightstage_command


@contextlib.contextmanager
def served(verb: str, domain_id: int, *args: str, timeout_s: float = 30.0):
    """Run `lightstage VERB --port 0 --domain-id D ARGS`; yield (process, address printed,
    e.g. 'http://127.0.0.1:41234/'); on exit Ctrl-C it and check it stopped with 0."""
    log = tempfile.NamedTemporaryFile('w+', prefix=f'lightstage_{verb}_', suffix='.log')
    proc = subprocess.Popen(lightstage_command(verb, '--port', '0', '--domain-id', str(domain_id), *args),
                            stdout=log, stderr=subprocess.STDOUT, env=ros_environment(domain_id))
    address = re.compile(r'(https?|ws)://[^\s;]+')
    try:
        deadline = time.monotonic() + timeout_s
        while not address.search(Path(log.name).read_text()):
            assert proc.poll() is None, \
                f'lightstage {verb} exited {proc.returncode}: {Path(log.name).read_text()}'
            assert time.monotonic() < deadline, f'lightstage {verb} printed no address in {timeout_s:g} s'
            time.sleep(0.1)
        proc.output = lambda: Path(log.name).read_text()
        yield proc, address.search(Path(log.name).read_text()).group(0).rstrip('/')
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise AssertionError(f'lightstage {verb} did not stop on Ctrl-C within 15 s:\n'
                                 f'{Path(log.name).read_text()}')
        output = Path(log.name).read_text()
        log.close()
    assert proc.returncode == 0, f'lightstage {verb} exited {proc.returncode}:\n{output}'
