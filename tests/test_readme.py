"""The README's command blocks run as printed, in order, after `make demo`.

Every ```sh block of README.md is either run here or named in NOT_RUN with the reason, so a
block added later cannot go unchecked. The run blocks are the README's terminals on the
demo's stage: a block that starts with `# terminal 1` keeps running (the graph) while the
`# terminal 2` blocks after it run, each command line as printed in one bash, each block
within a time bound; then terminal 1 gets Ctrl-C (SIGINT) and must exit 0.

`make demo` itself takes minutes; its stand-in is what it leaves in out/demo/ for these
blocks: the suite's stage capture (`stage_capture`, a smaller synthetic capture of the same
format) as out/demo/capture, an artifact trained on it as the demo's greedy one, and
out/demo/stage_params.yaml written by the demo's own `write_stage_params`. The blocks run in
a scratch folder whose .venv and src are the checkout's, in this test's own ROS domain.
"""
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from helpers.suite import fresh_domain_id

pytestmark = pytest.mark.process

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
# first line of a block -> why this test does not run it
NOT_RUN = {
    'make demo': 'the quick start itself: its stand-in is this module\'s stage fixture',
    'lightstage synth data/synth': 'the reference of every verb: minutes of CPU per line '
                                   '(each verb has its own tests)',
    'lightstage up driver camera classifier acquisition --params src/lightstage_bringup/config/real_rig.yaml':
        'needs the real rig (a camera and an Arduino on the serial port)',
    'source /opt/ros/jazzy/setup.bash && source .venv/setup.bash':
        'needs a ROS 2 Jazzy install for the ros2 CLI (not on PyPI); the nodes it starts are '
        'the ones the terminal blocks start with `lightstage up`',
    'lightstage up classifier --params out/demo/replay_params.yaml --domain-id 42':
        "needs the demo's recorded stage session; tests/lightstage_recording/test_demo_bag.py "
        'replays one into an observing classifier',
}
BLOCK_TIMEOUT_S = {'terminal 1': 120.0, 'terminal 2': 900.0}
GRAPH_UP = re.compile(r'graph up')


def sh_blocks(text: str) -> list[str]:
    return re.findall(r'^```sh\n(.*?)^```', text, flags=re.S | re.M)


def _first_command(block: str) -> str:
    lines = [line for line in block.splitlines() if line.strip()]
    return lines[0].split('#')[0].strip() if lines else ''


def _role(block: str) -> str | None:
    first = block.lstrip().splitlines()[0]
    match = re.match(r'#\s*(terminal [12])\b', first)
    return match.group(1) if match else None


def test_every_sh_block_is_run_or_named_with_a_reason():
    unknown = [b.splitlines()[0] for b in sh_blocks(README.read_text())
               if _role(b) is None and _first_command(b) not in NOT_RUN]
    assert not unknown, f'README blocks neither run by {__name__} nor in its NOT_RUN: {unknown}'
    firsts = {_first_command(b) for b in sh_blocks(README.read_text())}
    assert set(NOT_RUN) <= firsts, f'NOT_RUN names blocks the README no longer has: {set(NOT_RUN) - firsts}'


@pytest.fixture
def demo_folder(tmp_path, stage_capture, stage_artifact_path):
    """A scratch checkout as `make demo` leaves it: .venv and src of this one, out/demo/ with a
    capture, the greedy artifact and stage_params.yaml."""
    from lightstage_bringup.demo import write_stage_params
    (tmp_path / '.venv').symlink_to(ROOT / '.venv')
    (tmp_path / 'src').symlink_to(ROOT / 'src')
    demo = tmp_path / 'out' / 'demo'
    demo.mkdir(parents=True)
    (demo / 'capture').symlink_to(stage_capture)
    artifact = demo / 'greedy_sigma3.npz'
    shutil.copy(stage_artifact_path, artifact)
    first = sorted(p.relative_to(stage_capture).as_posix() for p in stage_capture.glob('*/*/*') if p.is_dir())[0]
    write_stage_params(demo, demo / 'capture', str(artifact), first)
    return tmp_path


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(('VIRTUAL_ENV', 'AMENT_', 'ROS_'))}
    env['ROS_DOMAIN_ID'] = str(fresh_domain_id())
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return env


def _stop(proc: subprocess.Popen, timeout_s: float = 30.0) -> int:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in terminal 1
        try:
            return proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
    return proc.returncode


def _wait_for_line(proc: subprocess.Popen, log: Path, pattern: re.Pattern, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pattern.search(log.read_text(errors='replace')):
            return
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    raise AssertionError(f'terminal 1 did not print {pattern.pattern!r} within {timeout_s} s '
                         f'(exit {proc.poll()}):\n{log.read_text(errors="replace")[-3000:]}')


def test_the_readme_blocks_on_the_demos_stage_run_as_printed(demo_folder):
    blocks = [b for b in sh_blocks(README.read_text()) if _role(b)]
    assert [_role(b) for b in blocks][:1] == ['terminal 1'], 'the run blocks start with a terminal 1'
    env = _env()
    background, log = None, None
    try:
        for i, block in enumerate(blocks):
            role = _role(block)
            if role == 'terminal 1':
                if background is not None:
                    assert _stop(background) == 0, log.read_text(errors='replace')[-3000:]
                log = demo_folder / f'terminal1_{i}.log'
                background = subprocess.Popen(['bash', '-e', '-c', block], cwd=demo_folder, env=env,
                                              stdout=log.open('w'), stderr=subprocess.STDOUT,
                                              start_new_session=True)
                _wait_for_line(background, log, GRAPH_UP, BLOCK_TIMEOUT_S[role])
                continue
            result = subprocess.run(['bash', '-e', '-c', block], cwd=demo_folder, env=env,
                                    capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S[role])
            assert result.returncode == 0, (f'README block failed (exit {result.returncode}):\n{block}\n'
                                            f'--- stdout\n{result.stdout[-3000:]}\n--- stderr\n{result.stderr[-3000:]}')
        if background is not None:
            rc = _stop(background)
            background = None
            assert rc == 0, f'terminal 1 did not stop cleanly on Ctrl-C (exit {rc}):\n{log.read_text()[-3000:]}'
    finally:
        if background is not None and background.poll() is None:
            os.killpg(background.pid, signal.SIGKILL)
            background.wait()
