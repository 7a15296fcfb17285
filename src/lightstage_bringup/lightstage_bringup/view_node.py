"""`lightstage view`'s node: the graph's topics, as they are, on a Foxglove WebSocket server.

Like foxglove_bridge on a full ROS install: every topic the selection takes (by default all
but the hidden ones: images, /illumination, results, /diagnostics, the Classify and
ApplyPatterns calls' service events, ...) is subscribed *raw* (serialized CDR, not decoded)
with a QoS matched to its publishers (the recorder's rule, `recording.subscription_qos`) and
logged unchanged to a foxglove-sdk channel with message encoding ``cdr`` and the type's
``ros2msg`` schema (its .msg text and dependencies, as a bag stores it), so Foxglove and
Lichtblick decode and show them with their ROS panels. New topics are picked up every
`discovery_period_s`. Started by `view_cli.main` after the ROS environment is set.
"""
from __future__ import annotations

import time

import foxglove
from lightstage_recording.bag_ros import (from_rclpy_qos, new_published_topics,
                                          to_rclpy_qos)
from lightstage_recording.msg_definitions import DefinitionNotFoundError
from lightstage_recording.recording import TopicSelector, subscription_qos
from rclpy.node import Node

from lightstage_bringup.view_channels import ros2_schema

VIEW_NODE = 'view'


class ViewNode(Node):
    """Subscribes to the graph and logs each message to its Foxglove channel."""

    def __init__(self, selector: TopicSelector, discovery_period_s: float = 0.5,
                 qos_depth: int = 100, context: foxglove.Context | None = None,
                 node_name: str = VIEW_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.selector = selector
        self.qos_depth = qos_depth
        self.fox_context = context
        self.channels: dict[str, foxglove.Channel] = {}
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
            channel = foxglove.Channel(topic, schema=schema, message_encoding='cdr',
                                       context=self.fox_context)
            qos = subscription_qos([from_rclpy_qos(p.qos_profile) for p in publishers], self.qos_depth)
            self.channels[topic] = channel
            self._served[topic] = self.create_subscription(
                cls, topic, self._forward(channel), to_rclpy_qos(qos), raw=True)
            self.get_logger().info(f'serving {topic} ({type_name}; {qos.reliability})')

    def _skip(self, topic: str, why: str) -> None:
        self.skipped[topic] = why
        self.get_logger().warning(f'not serving {topic}: {why}')

    @staticmethod
    def _forward(channel: foxglove.Channel):
        def on_message(data: bytes) -> None:
            channel.log(bytes(data), log_time=time.time_ns())
        return on_message

    def destroy_node(self) -> None:
        for channel in self.channels.values():
            channel.close()
        super().destroy_node()
