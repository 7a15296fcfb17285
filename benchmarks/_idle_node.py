"""A node that only spins: what bench_graph_watcher.py starts (by module name, with benchmarks/
on the child's PYTHONPATH), so that the time it measures is the graph's, not a node's set-up."""
import rclpy
from rclpy.executors import ExternalShutdownException


def main() -> int:
    rclpy.init()
    node = rclpy.create_node('idle_node')
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    return 0
