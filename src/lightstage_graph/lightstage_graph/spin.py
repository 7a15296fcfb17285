"""Starting a node and running it until it is stopped: the one `main()` body of the
project's nodes (as in ros2/examples).

    def main(argv=None):
        init_node(sys.argv if argv is None else argv)
        return spin_until_stopped(CameraNode(), MultiThreadedExecutor(num_threads=4))

`init_node` is `rclpy.init` in the project's ROS environment, however the node was started
(`ros2 run` from a shell that did not source the setup file included), and logs what that
changed. Ctrl-C (SIGINT), SIGTERM and an external `rclpy.shutdown()` are all a stop: the
node is destroyed (a node that holds hardware releases it in its `destroy_node`), rclpy
shut down, exit code 0.
"""
from __future__ import annotations

import rclpy
import rclpy.logging
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from .params import ParameterError, params_files_of, read_params_file
from .ros_env import apply_node_environment


def init_node(args: list[str] | None = None) -> None:
    """`rclpy.init(args=args)` after giving this process the project's ROS environment
    (LOCALHOST discovery, the Fast DDS profile: `ros_env`); logs what that changed."""
    message = apply_node_environment()
    for path in params_files_of(args):  # rcl's own parse error is a traceback without the line
        try:
            read_params_file(path)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
    rclpy.init(args=args)
    if message:
        rclpy.logging.get_logger('ros_env').info(message)


def spin_until_stopped(node: Node, executor: Executor | None = None) -> int:
    """Spin `node` on `executor` (default: single-threaded) until stopped, then destroy it
    and shut rclpy down; returns 0."""
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
