"""Shared by the bring-up tests: a domain id per test, and the environment for children."""
import itertools
import os
import sys
from pathlib import Path

from lightstage_graph.ros_env import ros_environment

HERE = Path(__file__).resolve().parent
_counter = itertools.count()


def fresh_domain_id() -> int:
    """A ROS domain id for one test: 1..99 (apart from the suite's 100..199), from the pid.

    Domains below 100 also keep every RTPS port under 32768, i.e. outside the ephemeral
    port range (tests/lightstage_graph/test_ros_environment.py relies on that to tell listening ports from send sockets).
    """
    return 1 + (os.getpid() * 7 + next(_counter)) % 99


def child_environment(domain_id: int, *extra_paths: Path) -> dict[str, str]:
    """The project ROS environment plus this directory (the fake nodes) on PYTHONPATH."""
    env = ros_environment(domain_id)
    paths = [str(p) for p in (HERE, *extra_paths)]
    if env.get('PYTHONPATH'):
        paths.append(env['PYTHONPATH'])
    env['PYTHONPATH'] = os.pathsep.join(paths)
    return env


def launcher_argv(*args: str, record: bool = False) -> list[str]:
    """`lightstage up ARGS` through the CLI dispatcher, run by this interpreter; without the
    recorder unless `record` (a test that records chooses where with --bag-dir)."""
    return [sys.executable, '-m', 'lightstage_bringup.cli', 'up', *args, *([] if record else ['--no-record'])]


def pid_alive(pid: int) -> bool:
    """The process exists and is not a zombie (a zombie still answers kill(pid, 0))."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f'/proc/{pid}/stat') as f:
        return f.read().split(')')[-1].split()[0] != 'Z'
