"""Shared by the bring-up tests: a domain id per test (the suite's one counter), and the
environment for children."""
import os
import sys
from pathlib import Path

from lightstage_graph.ros_env import ros_environment

from helpers.ros import NODE_SCRIPTS
from helpers.suite import fresh_domain_id  # noqa: F401 (for the tests)


def child_environment(domain_id: int, *extra_paths: Path) -> dict[str, str]:
    """The project ROS environment plus the stand-in node scripts (helpers/nodes) on PYTHONPATH."""
    env = ros_environment(domain_id)
    paths = [str(p) for p in (NODE_SCRIPTS, *extra_paths)]
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
