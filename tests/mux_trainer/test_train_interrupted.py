"""Ctrl-C during `lightstage train --method learned` ends with one line and exit 130, not a
traceback (the verb has nothing to clean up: the artifact is written only at the end)."""
import signal
import subprocess
import threading

import pytest

from helpers.suite import lightstage_command

pytestmark = pytest.mark.process


def test_ctrl_c_during_learned_training_ends_with_one_line_and_exit_130(stage_capture, tmp_path):
    out = tmp_path / 'learned.npz'
    proc = subprocess.Popen(lightstage_command('train', str(stage_capture), '--method', 'learned',
                                               '--max-images', '4', '--steps', '100000',
                                               '--out', str(out)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    started = threading.Event()

    def read():
        for line in proc.stderr:
            lines.append(line)
            started.set()   # the first progress line: the training is under way
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert started.wait(120), 'the training printed no progress'
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    reader.join(10)
    err = ''.join(lines)
    assert proc.returncode == 130, err
    assert 'Traceback' not in err and err.rstrip().endswith('lightstage train: interrupted (Ctrl-C)')
    assert not out.exists()
