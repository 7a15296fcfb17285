"""The one place that sets up the ROS environment for every process the project starts.

Discovery and data stay on this machine: Fast DDS gets the project's profile (shared memory
with a segment large enough for 800 x 800 mono16 images unfragmented, UDPv4 on 127.0.0.1
only, discovery by unicast to 127.0.0.1), and ROS_AUTOMATIC_DISCOVERY_RANGE is
`discovery_range`'s choice: SYSTEM_DEFAULT while that profile is the one Fast DDS reads,
LOCALHOST otherwise (a profile of the user's, another RMW). Not LOCALHOST with the profile:
rmw_fastrtps 8.4's LOCALHOST appends an unrestricted UDPv4 transport to the profile's, which
binds send sockets on 0.0.0.0 and on every interface's address. The install prefix is on AMENT_PREFIX_PATH (so `ros2 run` and
ament_index_python find the project's packages), and the domain id is explicit. Pure
Python, no rclpy import, so it can run before rclpy is loaded.

Who applies it: `lightstage up` and the test suite to their children, every node at
start-up (`apply_node_environment`, however it was started), and a shell that sources
`<venv>/setup.bash`, which evaluates `python -m lightstage_graph.ros_env` (this module's
`main`: the shell commands that make the environment so).
"""
from __future__ import annotations

import os
import shlex
import sys
from importlib import resources
from pathlib import Path

FASTDDS_PROFILE_NAME = 'fastdds_profile.xml'
PACKAGE = 'lightstage_graph'


def fastdds_profile_path() -> Path:
    """Path of the Fast DDS XML profile shipped with this package."""
    return Path(str(resources.files(PACKAGE) / 'config' / FASTDDS_PROFILE_NAME))


def is_project_profile(path: str | None) -> bool:
    """Whether `path` is the project's Fast DDS profile: this package's file, or a copy of it
    (the launch file names the one installed under share/lightstage_graph)."""
    if not path:
        return False
    ours = fastdds_profile_path()
    try:
        return Path(path).resolve() == ours.resolve() or Path(path).read_bytes() == ours.read_bytes()
    except OSError:
        return False


def discovery_range(env: dict[str, str]) -> str:
    """ROS_AUTOMATIC_DISCOVERY_RANGE for `env`: SYSTEM_DEFAULT when rmw_fastrtps reads the
    project's profile, which confines discovery and data to loopback and shared memory
    (rmw then applies nothing of its own); LOCALHOST for anything else."""
    if (env.get('RMW_IMPLEMENTATION') == 'rmw_fastrtps_cpp'
            and is_project_profile(env.get('FASTRTPS_DEFAULT_PROFILES_FILE'))):
        return 'SYSTEM_DEFAULT'
    return 'LOCALHOST'


def ament_prefix() -> Path | None:
    """The install prefix holding this package's ament index marker (a venv: the venv; colcon:
    install/lightstage_graph), or None when it runs from a source tree."""
    for prefix in Path(__file__).resolve().parents:
        if (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file():
            return prefix
    return None


def ros_environment(domain_id: int | None = None, base: dict[str, str] | None = None) -> dict[str, str]:
    """Return a copy of `base` (default: os.environ) with the project's ROS settings.

    The discovery range is `discovery_range`'s (SYSTEM_DEFAULT with the project's profile,
    LOCALHOST otherwise); ROS_STATIC_PEERS is removed. An explicit `domain_id` wins over
    ROS_DOMAIN_ID in `base`; a profile already chosen
    by the user (FASTRTPS_DEFAULT_PROFILES_FILE) is kept; the install prefix is put first
    on AMENT_PREFIX_PATH unless it is on it already.
    """
    env = dict(os.environ if base is None else base)
    env.pop('ROS_STATIC_PEERS', None)
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    env.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(fastdds_profile_path()))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = discovery_range(env)
    prefix = ament_prefix()
    prefixes = [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    if prefix is not None and str(prefix) not in prefixes:
        env['AMENT_PREFIX_PATH'] = os.pathsep.join([str(prefix), *prefixes])
    if domain_id is not None:
        if not 0 <= domain_id <= 232:
            raise ValueError(f'ROS domain id {domain_id} is out of range: use 0..232')
        env['ROS_DOMAIN_ID'] = str(domain_id)
    return env


def apply_ros_environment(domain_id: int | None = None) -> None:
    """Set the project's ROS settings in this process (call before importing rclpy)."""
    env = ros_environment(domain_id)
    # Static peers are contacted even with LOCALHOST discovery: remove, not just override.
    for name in set(os.environ) - set(env):
        del os.environ[name]
    os.environ.update(env)


def _changes(before: dict[str, str], after: dict[str, str]) -> dict[str, str | None]:
    """{name: new value, or None when removed} for every variable that differs."""
    return {n: after.get(n) for n in sorted(set(before) | set(after)) if before.get(n) != after.get(n)}


def apply_node_environment() -> str | None:
    """Give this node process the project's ROS environment, however it was started (`ros2
    run` from a shell that did not source the setup file, a console script, ...); call it
    before rclpy.init. Returns a line saying what it changed, for the node's log, or None
    when the environment was already the project's (`lightstage up`, the launch file, a
    shell that sourced `<venv>/setup.bash`)."""
    before = dict(os.environ)
    apply_ros_environment()
    changed = _changes(before, dict(os.environ))
    if not changed:
        return None
    what = ', '.join(f'{n}={v} (was {before[n] if n in before else "unset"})' if v is not None
                     else f'unset {n} (was {before[n]})' for n, v in changed.items())
    return (f'ROS environment: {what}; the project\'s settings (lightstage_graph.ros_env), '
            f'which a shell gets from `source <venv>/setup.bash`')


def apply_node_environment_and_say(node_name: str) -> None:
    """`apply_node_environment`, saying on stderr what it changed: for the mains that set
    up their process before rclpy's logging (the recorder and the player)."""
    message = apply_node_environment()
    if message:
        print(f'{node_name}: {message}', file=sys.stderr, flush=True)


def shell_commands(base: dict[str, str] | None = None) -> str:
    """POSIX shell commands that turn the environment `base` (default: os.environ) into the
    project's ROS environment: what `<venv>/setup.bash` evaluates."""
    base = dict(os.environ if base is None else base)
    return ''.join(f'export {n}={shlex.quote(v)}\n' if v is not None else f'unset {n}\n'
                   for n, v in _changes(base, ros_environment(base=base)).items())


def main() -> int:
    """`python -m lightstage_graph.ros_env`: print the shell commands (for `eval`)."""
    sys.stdout.write(shell_commands())
    return 0


if __name__ == '__main__':
    sys.exit(main())
