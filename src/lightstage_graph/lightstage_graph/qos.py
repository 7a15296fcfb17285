"""The QoS profiles of the light stage's topics, defined once (publishers and subscribers)."""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# camera/image_raw (and camera_info, frame_lost): reliable, keep-last 32 (not SensorData's
# best-effort depth 5): a classification needs every frame of its trigger sequence and matches
# them by stamp, so a dropped frame is a failed classification, not a skipped video frame.
# 32 frames cover one 32-pattern sequence.
IMAGE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32,
                       reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

# /illumination: one message per trigger, every one matters
ILLUMINATION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)

# A service that queues its calls (the classifier's /lightstage/classify): as the services'
# default (reliable, volatile) but 1000 requests deep, so that a burst of concurrent calls
# waits in the request reader until the executor takes them; the default depth, 10, drops
# the oldest requests of a larger burst, which are then never answered.
QUEUED_SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.VOLATILE)

# A service client's reply reader. Every client of a service receives every reply the server
# sends, to whichever client, and drops the ones not addressed to it (rmw_fastrtps and
# rmw_cyclonedds alike: ros2/rclcpp#2397); the reader keeps the last `depth` replies the
# executor has not taken yet. So a client loses its reply when `depth` more replies, to any
# client of the service, arrive before its executor takes it: at the default
# depth, 10, 30 calls at once in one process got 15-27 of 30 replies, and a reply held while
# 29 replies to another client arrived was lost (tests/lightstage_bringup/
# test_web_classify_burst.py); at depth 1000 none was lost. Every client the project makes
# (`service_client`) reads replies 1000 deep; a client made elsewhere needs the same depth
# to be safe in a burst (`ros2 service call` makes one client at depth 10).
SERVICE_CLIENT_QOS = QUEUED_SERVICE_QOS


def service_client(node, srv_type, name: str, **kwargs):
    """`node.create_client` with the reply reader 1000 deep (`SERVICE_CLIENT_QOS`); keyword
    arguments (callback_group, ...) go to create_client."""
    return node.create_client(srv_type, name, qos_profile=SERVICE_CLIENT_QOS, **kwargs)
