"""Starting a node and running it until it is stopped: the one `main()` body of the
project's nodes.

    init_node(argv)
    return spin_until_stopped(CameraNode(), MultiThreadedExecutor(num_threads=4))

`init_node` is `rclpy.init` in the project's ROS environment, however the node was started
(`ros2 run` from a shell that did not source the setup file included).

Ctrl-C (SIGINT), SIGTERM and an external `rclpy.shutdown()` are all a stop: the node is
destroyed, rclpy shut down, exit code 0. (The driver has its own `main`: it releases the
stage on the way out and depends on no other project package.)
"""
from __future__ import annotations

import rclpy
import rclpy.logging
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


def init_node(args: list[str] | None = None) -> None:
    """`rclpy.init(args=args)` after giving this process the project's ROS environment
    (LOCALHOST discovery, the Fast DDS profile: `lightstage_bringup.ros_env`); logs what
    that changed, or what is missing when lightstage_bringup is not installed."""
    try:  # lightstage_bringup depends on this package, so the import is optional
        from lightstage_bringup.ros_env import apply_node_environment
    except ImportError:
        message = MISSING_ENVIRONMENT
    else:
        message = apply_node_environment()
    rclpy.init(args=args)
    if message:
        rclpy.logging.get_logger('ros_env').info(message)


# what a node says when it cannot apply the project's ROS environment itself
MISSING_ENVIRONMENT = ('lightstage_bringup is not installed, so this node runs in the ROS '
                       'environment it was given: the project expects '
                       'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and FASTRTPS_DEFAULT_PROFILES_FILE '
                       'naming lightstage_bringup\'s fastdds_profile.xml (large images)')


def spin_until_stopped(node: Node, executor: Executor | None = None) -> int:
    """Spin `node` on `executor` (default: single-threaded) until stopped; returns 0."""
    executor = executor if executor is not None else SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: BLE001
        # a SIGINT that shuts the context down while spin builds its wait set surfaces as
        # an RCLError, not ExternalShutdownException (ros2/rclpy#1166): a stop all the same
        if rclpy.ok():
            raise
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
