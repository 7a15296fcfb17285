"""The light stage's graph contract, one idea per module; every node is written against it.

Pure (no rclpy; usable anywhere):
    names         topic, service, action and default node names
    params        parameter descriptors with ranges; declaring them and reading them back
    stamps        builtin_interfaces/Time <-> nanoseconds
    errors        StageError, MissingImagesError
    frames        mono16 decoding and ImageMatcher (images matched to trigger stamps)
    diagnostics   a DiagnosticArray publisher handed a node (as diagnostic_updater)
    exits         how a process ended, in words
    limits        the ranges of gain, exposure and dimmer every package checks against
    output        printing to a pipe whose reader may go away (`| head -1`)
    ros_env       the project's ROS environment (`python -m lightstage_graph.ros_env`)
    goal_watch    ServerWatch: when a client gives up on an action server that went away
    deadline      ExitDeadline: a CLI call that ends, whatever it is stuck in
ROS (rclpy):
    qos           the image and illumination QoS profiles
    spin          init_node / spin_until_stopped: every node's main()
    stage_client  light patterns through the driver and collect the frames of their triggers
    graph_client  a private-context client for the CLI verbs, the demo and the tests
"""
