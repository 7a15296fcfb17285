"""Bring-up of the whole graph: the `lightstage` command, `lightstage up`, the demo, the
operator's page and the Foxglove view.

The command and its processes (no rclpy at import):
    cli              the `lightstage` entry point: each verb's module imported only when used
    demo             `lightstage demo`: synthesise, train, classify on the simulated stage, record
    launcher         `lightstage up`: the project's nodes as processes, a graph check, a recording
    supervisor       child processes: start, forward their output, notice deaths, stop in order
    acquisition_cli  `lightstage capture` and `lightstage calibrate`: the acquisition node's actions
    classify_cli     `lightstage classify` (the ``/lightstage/classify`` service)
The operator's page (`lightstage web`, docs/WEB.md):
    web_state        what the page shows, as plain data (`PageState`; no rclpy)
    web_requests     the page's API requests checked field by field, the goals they make
    web_app          the aiohttp server over a `PageState` and a bridge to the graph (no rclpy)
    web_node         the bridge: hands the graph's messages to the page, its calls to the graph
    web_cli          `lightstage web`
The Foxglove / Lichtblick view (`lightstage view`, docs/WEB.md):
    view_channels    the schemas and the layout a Foxglove client is given (no rclpy)
    view_server      the Foxglove WebSocket protocol server (both subprotocol names, the Host
                     and Origin guard, bounded per-client queues; aiohttp, no rclpy)
    view_node        the graph's topics on that server
    view_cli         `lightstage view`

The launch file, the parameter files (simulated stage, real rig) and the Foxglove layout are
installed to share/lightstage_bringup/. Recording and replay are lightstage_recording's; the
ROS environment is `lightstage_graph.ros_env`. Importing the package imports none of them.
"""

__all__ = ['cli', 'demo', 'launcher', 'supervisor', 'acquisition_cli', 'classify_cli',
           'web_state', 'web_requests', 'web_app', 'web_node', 'web_cli', 'view_channels', 'view_server',
           'view_node', 'view_cli']
