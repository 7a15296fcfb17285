"""Stands in for a node that starts but never joins the ROS graph (e.g. stuck in set-up)."""
import time


def main() -> int:
    print('starting, but never creating a ROS node', flush=True)
    time.sleep(120)
    return 0
