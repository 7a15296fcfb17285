"""What `lightstage view` tells a Foxglove client about each topic (no rclpy): the schema of a
ROS type as foxglove_bridge gives it (encoding ``ros2msg``: the type's .msg text and its
dependencies, the text a bag stores), and where the stage's Foxglove layout is installed."""
from __future__ import annotations

import sys
from pathlib import Path

import foxglove

from lightstage_recording.msg_definitions import full_definition

LAYOUT_FILE = 'foxglove_layout.json'


def ros2_schema(type_name: str) -> foxglove.Schema:
    """``pkg/msg/Type`` -> its ``ros2msg`` schema; DefinitionNotFoundError when its interface
    files are not installed here."""
    return foxglove.Schema(name=type_name, encoding='ros2msg',
                           data=full_definition(type_name).encode())


def layout_path() -> Path | None:
    """The shipped layout (share/lightstage_bringup/config/), installed or in the source tree."""
    for candidate in (Path(sys.prefix) / 'share' / 'lightstage_bringup' / 'config' / LAYOUT_FILE,
                      Path(__file__).resolve().parents[1] / 'config' / LAYOUT_FILE):
        if candidate.is_file():
            return candidate
    return None
