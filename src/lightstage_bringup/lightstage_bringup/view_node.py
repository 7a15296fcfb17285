"""`lightstage view`'s node: the graph's topics, as they are, on a Foxglove WebSocket server.

Like foxglove_bridge on a full ROS install: every topic the selection takes (by default all
but the hidden ones: images, /illumination, results, /diagnostics, the Classify and
ApplyPatterns calls' service events, ...) is subscribed *raw* (serialized CDR, not decoded)
with a QoS matched to its publishers (the recorder's rule, `recording.subscription_qos`) and
sent unchanged on a channel of the Foxglove server (`view_server`) with message encoding
``cdr`` and the type's ``ros2msg`` schema (its .msg text and dependencies, as a bag stores it),
so Foxglove and Lichtblick decode and show them with their ROS panels. New topics are picked up every
`discovery_period_s`. Started by `view_cli.main` after the ROS environment is set.
"""
from __future__ import annotations

import time

from lightstage_recording.bag_ros import (from_rclpy_qos, new_published_topics,
                                          to_rclpy_qos)
from lightstage_recording.msg_definitions import DefinitionNotFoundError
from lightstage_recording.recording import TopicSelector, subscription_qos
from rclpy.node import Node

from lightstage_bringup.view_channels import MESSAGE_ENCODING, SCHEMA_ENCODING, ros2_schema
from lightstage_bringup.view_server import FoxgloveServer

VIEW_NODE = 'view'


class ViewNode(Node):
    """Subscribes to the graph and sends each message on its Foxglove channel."""

    def __init__(self, selector: TopicSelector, server: FoxgloveServer,
                 discovery_period_s: float = 0.5, qos_depth: int = 100,
                 node_name: str = VIEW_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.selector = selector
        self.qos_depth = qos_depth
        self.server = server
        self.channels: dict[str, int] = {}   # topic -> channel id
        self._served: dict[str, object] = {}
        self.skipped: dict[str, str] = {}
        self.create_timer(discovery_period_s, self.discover)
        self.discover()

    def discover(self) -> None:
        known = self._served.keys() | self.skipped.keys()
        for topic, type_name, cls, publishers, problem in new_published_topics(self, known, self.selector):
            if problem:
                self._skip(topic, problem)
                continue
            try:
                schema = ros2_schema(type_name)
            except DefinitionNotFoundError as exc:
                self._skip(topic, str(exc))
                continue
            channel = self.server.add_channel(topic, encoding=MESSAGE_ENCODING, schema_name=type_name,
                                              schema=schema, schema_encoding=SCHEMA_ENCODING)
            qos = subscription_qos([from_rclpy_qos(p.qos_profile) for p in publishers], self.qos_depth)
            self.channels[topic] = channel
            self._served[topic] = self.create_subscription(
                cls, topic, self._forward(channel), to_rclpy_qos(qos), raw=True)
            self.get_logger().info(f'serving {topic} ({type_name}; {qos.reliability})')

    def _skip(self, topic: str, why: str) -> None:
        self.skipped[topic] = why
        self.get_logger().warning(f'not serving {topic}: {why}')

    def _forward(self, channel: int):
        log = self.server.log

        def on_message(data: bytes) -> None:
            log(channel, data, time.time_ns())
        return on_message
