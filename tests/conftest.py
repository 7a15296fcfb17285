"""Suite-wide setup: every ROS participant of the test run stays on loopback.

This runs before any test module imports rclpy, so in-process nodes get LOCALHOST
discovery, the project's Fast DDS profile and a domain id of this run's own (tests that
start processes choose their own ids through `lightstage_bringup.ros_env`).
"""
import os

from lightstage_bringup.ros_env import apply_ros_environment

TEST_RUN_DOMAIN_ID = 100 + os.getpid() % 100
apply_ros_environment(domain_id=int(os.environ.get('LIGHTSTAGE_TEST_DOMAIN_ID', TEST_RUN_DOMAIN_ID)))
