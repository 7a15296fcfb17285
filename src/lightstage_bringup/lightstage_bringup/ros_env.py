"""The one place that sets up the ROS environment for every process the project starts.

Discovery stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), Fast DDS gets
a profile with a large shared-memory segment so that 800 x 800 mono16 images travel
without fragmentation, and the domain id is explicit. Pure Python, no rclpy import, so
it can run before rclpy is loaded.
"""
from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

FASTDDS_PROFILE_NAME = 'fastdds_profile.xml'


def fastdds_profile_path() -> Path:
    """Path of the Fast DDS XML profile shipped with this package."""
    return Path(str(resources.files('lightstage_bringup') / 'config' / FASTDDS_PROFILE_NAME))


def ros_environment(domain_id: int | None = None, base: dict[str, str] | None = None) -> dict[str, str]:
    """Return a copy of `base` (default: os.environ) with the project's ROS settings.

    An explicit `domain_id` wins over ROS_DOMAIN_ID in `base`; a profile already chosen
    by the user (FASTRTPS_DEFAULT_PROFILES_FILE) is kept.
    """
    env = dict(os.environ if base is None else base)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_STATIC_PEERS', None)
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    env.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(fastdds_profile_path()))
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
