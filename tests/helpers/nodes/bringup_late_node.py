"""Stands in for a node that joins the ROS graph late (a slow import or set-up before it
creates its node): the fake node after a 3 s wait."""
import time

import bringup_fake_node


def main() -> int:
    time.sleep(3.0)
    return bringup_fake_node.main()
