"""A test module says `process` or it is not (tests/helpers/markers.py): the `fast` tests run
under a guard that fails a test starting a process, and `-m fast` skips a module by its own
`pytestmark` line."""
import multiprocessing
import os
import subprocess
import sys

import pytest

from helpers.markers import ProcessStartInFastTest, declares_process


def test_a_test_not_marked_process_cannot_start_one(process_guard):
    assert process_guard is not None, 'this test is fast, so it runs under the guard'
    with pytest.raises(ProcessStartInFastTest, match='pytestmark = pytest.mark.process'):
        subprocess.run([sys.executable, '-c', 'pass'], check=True)
    for method in ('spawn', 'fork', 'forkserver'):
        with pytest.raises(ProcessStartInFastTest):
            multiprocessing.get_context(method).Process(target=print).start()
    with pytest.raises(ProcessStartInFastTest):
        os.system('true')
    assert process_guard.attempts and all(isinstance(a, str) for a in process_guard.attempts)
    process_guard.attempts.clear()  # the refusals were the point: the test passes


def test_a_swallowed_refusal_still_fails_the_test(process_guard):
    try:
        subprocess.run(['true'])
    except RuntimeError:
        pass  # code under test that catches every error still leaves the attempt recorded
    assert process_guard.attempts == ['subprocess.Popen']
    process_guard.attempts.clear()


@pytest.mark.process
def test_a_test_marked_process_may_start_one(process_guard):
    assert process_guard is None
    subprocess.run([sys.executable, '-c', 'pass'], check=True)


@pytest.mark.parametrize('text, declared', [
    ('pytestmark = pytest.mark.process\n', True),
    ('import pytest\n\npytestmark = [pytest.mark.ros, pytest.mark.process]\n', True),
    ('pytestmark = [\n    pytest.mark.ros,\n    pytest.mark.process,\n]\n', True),
    ('pytestmark = pytest.mark.ros\n', False),
    ('"""Starts no process: rclpy, subprocess and Popen are only named here."""\n', False),
    ('@pytest.mark.process\ndef test_one(): pass\n', False),
], ids=['one', 'list', 'multiline_list', 'other_marker', 'only_named', 'one_test_marked'])
def test_a_module_is_process_by_its_pytestmark_line_only(text, declared):
    assert declares_process(text) is declared
