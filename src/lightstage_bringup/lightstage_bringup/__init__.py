"""Bring-up of the whole graph: the lightstage CLI, ROS environment, launch files, configuration, recording and replay."""
