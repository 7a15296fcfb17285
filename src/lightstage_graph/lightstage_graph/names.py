"""Every name the graph is wired by, defined once: topics, services, actions, node names.

The node names are each node's default name (what `ros2 run` gives it), its name in
`lightstage up` and the launch file, and its section in the params YAML.
"""

# nodes
DRIVER_NODE = 'driver'
CAMERA_NODE = 'camera'
CLASSIFIER_NODE = 'classifier'
ACQUISITION_NODE = 'acquisition'
TRAINER_NODE = 'trainer'
RECORDER_NODE = 'recorder'
PLAYER_NODE = 'player'

# topics
ILLUMINATION_TOPIC = '/illumination'   # IlluminationState, one per trigger (driver)
# The camera's topics are relative, in its namespace as ROS camera drivers put them (remappable:
# `-r camera/image_raw:=...`); with no namespace they resolve to /camera/image_raw etc.
IMAGE_TOPIC = 'camera/image_raw'       # sensor_msgs/Image mono16, stamp = trigger stamp (camera)
CAMERA_INFO_TOPIC = 'camera/camera_info'  # sensor_msgs/CameraInfo, same header as each image
FRAME_LOST_TOPIC = 'camera/frame_lost'    # FrameLost: a trigger's image that will not come, and why
RESULT_TOPIC = '/lightstage/result'    # ClassificationResult (classifier)
DIAGNOSTICS_TOPIC = '/diagnostics'     # DiagnosticArray (driver, camera, classifier)

# services
APPLY_PATTERNS_SERVICE = '/lightstage/apply_patterns'  # ApplyPatterns (driver)
CLASSIFY_SERVICE = '/lightstage/classify'              # Classify (classifier)

# actions
TRAIN_ACTION = '/lightstage/train'                     # Train (trainer)
CAPTURE_ACTION = '/lightstage/capture_model'           # CaptureModel (acquisition)
CALIBRATE_ACTION = '/lightstage/calibrate_noise'       # CalibrateNoise (acquisition)


SERVICE_EVENT_SUFFIX = '/_service_event'


def resolved(topic: str, namespace: str = '/') -> str:
    """The full name of `topic` for a node in `namespace` (default: none), as the recorder,
    the player and graph queries need it: 'camera/image_raw' -> '/camera/image_raw'."""
    if topic.startswith('/'):
        return topic
    return f"{namespace.rstrip('/')}/{topic}"


def service_event_topic(service: str) -> str:
    """The topic a service's introspection publishes its calls on."""
    return f'{service}{SERVICE_EVENT_SUFFIX}'
