"""SHIM(issue 13): remove at merge. The ROS environment moved to `lightstage_graph.ros_env`;
the recording modules (recorder_node, player_node, bag_cli) still import it from here."""
from lightstage_graph.ros_env import (apply_node_environment,  # noqa: F401  SHIM(issue 13): remove at merge
                                      apply_node_environment_and_say, apply_ros_environment,
                                      ros_environment)
