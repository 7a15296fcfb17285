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
IMAGE_TOPIC = '/image_raw'             # sensor_msgs/Image mono16, stamp = trigger stamp (camera)
RESULT_TOPIC = '/lightstage/result'    # ClassificationResult (classifier)
DIAGNOSTICS_TOPIC = '/diagnostics'     # DiagnosticArray (driver, camera)

# services
APPLY_PATTERNS_SERVICE = '/lightstage/apply_patterns'  # ApplyPatterns (driver)
CLASSIFY_SERVICE = '/lightstage/classify'              # Classify (classifier)

# actions
TRAIN_ACTION = '/lightstage/train'                     # Train (trainer)
CAPTURE_ACTION = '/lightstage/capture_model'           # CaptureModel (acquisition)
CALIBRATE_ACTION = '/lightstage/calibrate_noise'       # CalibrateNoise (acquisition)


SERVICE_EVENT_SUFFIX = '/_service_event'


def service_event_topic(service: str) -> str:
    """The topic a service's introspection publishes its calls on."""
    return f'{service}{SERVICE_EVENT_SUFFIX}'
