"""Running a node until it is stopped: the one `main()` body of the project's nodes.

    rclpy.init(args=argv)
    return spin_until_stopped(CameraNode(), MultiThreadedExecutor(num_threads=4))

Ctrl-C (SIGINT), SIGTERM and an external `rclpy.shutdown()` are all a stop: the node is
destroyed, rclpy shut down, exit code 0. (The driver has its own `main`: it releases the
stage on the way out and depends on no other project package.)
"""
from __future__ import annotations

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


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
