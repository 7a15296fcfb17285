"""What `lightstage view` tells a Foxglove client about each topic (no rclpy): the schema of a
ROS type as foxglove_bridge gives it (encoding ``ros2msg``: the type's .msg text and its
dependencies, the text a bag stores), the server's metadata, and where the stage's Foxglove
layout is installed."""
from __future__ import annotations

import os
import sys
from pathlib import Path

from lightstage_recording.layout import ROS_DISTRO
from lightstage_recording.msg_definitions import full_definition

LAYOUT_FILE = 'foxglove_layout.json'
SCHEMA_ENCODING, MESSAGE_ENCODING = 'ros2msg', 'cdr'


def ros2_schema(type_name: str) -> str:
    """``pkg/msg/Type`` -> its ``ros2msg`` schema text; DefinitionNotFoundError when its
    interface files are not installed here."""
    return full_definition(type_name)


def server_metadata() -> dict[str, str]:
    """serverInfo's metadata: ``ROS_DISTRO`` (as foxglove_bridge sends it; Foxglove decodes
    ROS 2 messages by it), the sourced distribution's or the one the interfaces are built for."""
    return {'ROS_DISTRO': os.environ.get('ROS_DISTRO') or ROS_DISTRO}


def layout_path() -> Path | None:
    """The shipped layout (share/lightstage_bringup/config/), installed or in the source tree."""
    for candidate in (Path(sys.prefix) / 'share' / 'lightstage_bringup' / 'config' / LAYOUT_FILE,
                      Path(__file__).resolve().parents[1] / 'config' / LAYOUT_FILE):
        if candidate.is_file():
            return candidate
    return None
