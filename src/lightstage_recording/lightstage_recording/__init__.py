"""Recording and replay of a ROS 2 graph: rosbag2-compatible MCAP bags (docs/RECORDING.md).

One concern per module, the bag format ones pure Python (no rclpy), thin over the ``mcap``
library: `layout` (the bag directory and metadata.yaml), `qos` (QoS as rosbag2 stores it),
`msg_definitions` (schemas and type hashes), `summary` (what a bag holds), `writer`,
`scan` (one MCAP file record by record) and `reader`, `recover`, `export` (a copy every Python bag reader opens), `losses` (what a
recording lost: sequence gaps, unmatched service events), `formatting` (text for
people), `fileio` (durable writes), `exceptions`; `recording` (the recorder's and player's
rules). ROS side: `bag_ros`, `recorder_node`, `player_node`; `bag_cli` is
`lightstage record|play|bag`. The names below are the bag API.
"""
from .exceptions import BagError, BagWriteError
from .formatting import format_info, format_size, format_time
from .layout import default_bag_name
from .qos import QosProfile
from .reader import BagReader
from .recover import Recovery, recover_bag
from .summary import BagInfo, BagMessage, TopicInfo
from .writer import BagWriter

__all__ = ['BagError', 'BagInfo', 'BagMessage', 'BagReader', 'BagWriteError', 'BagWriter',
           'QosProfile', 'Recovery', 'TopicInfo', 'default_bag_name', 'format_info',
           'format_size', 'format_time', 'recover_bag']
