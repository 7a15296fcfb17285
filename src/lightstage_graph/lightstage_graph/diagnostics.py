"""A node's ``/diagnostics``, as `diagnostic_updater` does it: a small object handed the node
that publishes, every period and on demand, the DiagnosticArray of the node's status.

    self.diagnostics = DiagnosticsPublisher(self, 'light stage link', self._link_status, 1.0)

`task()` returns a `Report` (level, message, key/value pairs, hardware id); the status is
named ``<node name>: <what>``. No rclpy import: the node creates the publisher and timer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .names import DIAGNOSTICS_TOPIC

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


@dataclass
class Report:
    """One status: `level` OK / WARN / ERROR, a message, values (shown as strings)."""
    level: int
    message: str
    values: dict = field(default_factory=dict)
    hardware_id: str = ''


class DiagnosticsPublisher:
    """Publishes `task()`'s Report as ``<node name>: <what>`` on /diagnostics every
    `period_s` (and on `publish()`)."""

    def __init__(self, node, what: str, task: Callable[[], Report], period_s: float):
        self._node = node
        self.name = f'{node.get_name()}: {what}'
        self._task = task
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._timer = node.create_timer(period_s, self.publish)

    def publish(self) -> None:
        report = self._task()
        status = DiagnosticStatus(level=report.level, name=self.name, message=report.message,
                                  hardware_id=report.hardware_id,
                                  values=[KeyValue(key=k, value=str(v)) for k, v in report.values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)
