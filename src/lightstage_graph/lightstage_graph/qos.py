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
