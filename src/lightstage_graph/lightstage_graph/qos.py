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
# executor has not taken yet. At the default depth, 10, a burst of replies evicts some before
# they are taken, and those calls are never answered: 30 calls at once, from 30 clients or one,
# in one process got 15-27 of 30 replies at depth 10 and 30 of 30 at depth 1000. So every
# client the project makes (`service_client`) reads replies 1000 deep. A client made elsewhere
# with the default depth (`ros2 service call` makes one client per process for one call) is
# safe while it has fewer than 10 calls in flight with the other clients of its service.
SERVICE_CLIENT_QOS = QUEUED_SERVICE_QOS


def service_client(node, srv_type, name: str, **kwargs):
    """`node.create_client` with the reply reader 1000 deep (`SERVICE_CLIENT_QOS`); keyword
    arguments (callback_group, ...) go to create_client."""
    return node.create_client(srv_type, name, qos_profile=SERVICE_CLIENT_QOS, **kwargs)
