"""rclpy side of recording and replay: QoS conversion, message classes by type name, and the
read-only parameter descriptors of the recorder and player nodes."""
from __future__ import annotations

import importlib

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.duration import Duration
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile,
                       ReliabilityPolicy)

from .bag_format import INFINITE_NS, QosProfile
from .msg_definitions import split_type

_HISTORY = {HistoryPolicy.SYSTEM_DEFAULT: 'system_default', HistoryPolicy.KEEP_LAST: 'keep_last',
            HistoryPolicy.KEEP_ALL: 'keep_all', HistoryPolicy.UNKNOWN: 'unknown'}
_RELIABILITY = {ReliabilityPolicy.SYSTEM_DEFAULT: 'system_default',
                ReliabilityPolicy.RELIABLE: 'reliable', ReliabilityPolicy.BEST_EFFORT: 'best_effort',
                ReliabilityPolicy.UNKNOWN: 'unknown'}
_DURABILITY = {DurabilityPolicy.SYSTEM_DEFAULT: 'system_default',
               DurabilityPolicy.TRANSIENT_LOCAL: 'transient_local',
               DurabilityPolicy.VOLATILE: 'volatile', DurabilityPolicy.UNKNOWN: 'unknown'}
_LIVELINESS = {LivelinessPolicy.SYSTEM_DEFAULT: 'system_default',
               LivelinessPolicy.AUTOMATIC: 'automatic',
               LivelinessPolicy.MANUAL_BY_TOPIC: 'manual_by_topic',
               LivelinessPolicy.UNKNOWN: 'unknown'}
for _enum, _table in ((ReliabilityPolicy, _RELIABILITY), (DurabilityPolicy, _DURABILITY),
                      (LivelinessPolicy, _LIVELINESS)):
    if hasattr(_enum, 'BEST_AVAILABLE'):
        _table[_enum.BEST_AVAILABLE] = 'best_available'


def _ns(duration) -> int:
    ns = int(duration.nanoseconds)
    return INFINITE_NS if ns >= INFINITE_NS or ns < 0 else ns


def from_rclpy_qos(q: QoSProfile) -> QosProfile:
    """An rclpy profile (e.g. a discovered publisher's) as rosbag2 stores it."""
    return QosProfile(history=_HISTORY.get(q.history, 'unknown'), depth=int(q.depth),
                      reliability=_RELIABILITY.get(q.reliability, 'unknown'),
                      durability=_DURABILITY.get(q.durability, 'unknown'),
                      deadline_ns=_ns(q.deadline), lifespan_ns=_ns(q.lifespan),
                      liveliness=_LIVELINESS.get(q.liveliness, 'unknown'),
                      liveliness_lease_duration_ns=_ns(q.liveliness_lease_duration),
                      avoid_ros_namespace_conventions=bool(q.avoid_ros_namespace_conventions))


def _duration(ns: int) -> Duration:
    return Duration(nanoseconds=0) if ns >= INFINITE_NS else Duration(nanoseconds=int(ns))


def _policy(name: str, table: dict, default):
    value = {v: k for k, v in table.items()}.get(name, default)
    return default if getattr(value, 'name', '') == 'UNKNOWN' else value


def to_rclpy_qos(q: QosProfile) -> QoSProfile:
    """A profile for a subscription or publisher (infinite durations as rclpy's default 0;
    unknown policies as keep-last / reliable / volatile / automatic)."""
    history = _policy(q.history, _HISTORY, HistoryPolicy.KEEP_LAST)
    if history == HistoryPolicy.SYSTEM_DEFAULT:
        history = HistoryPolicy.KEEP_LAST
    return QoSProfile(
        history=history, depth=max(1, int(q.depth)),
        reliability=_policy(q.reliability, _RELIABILITY, ReliabilityPolicy.RELIABLE),
        durability=_policy(q.durability, _DURABILITY, DurabilityPolicy.VOLATILE),
        liveliness=_policy(q.liveliness, _LIVELINESS, LivelinessPolicy.AUTOMATIC),
        deadline=_duration(q.deadline_ns), lifespan=_duration(q.lifespan_ns),
        liveliness_lease_duration=_duration(q.liveliness_lease_duration_ns),
        avoid_ros_namespace_conventions=q.avoid_ros_namespace_conventions)


def message_class(type_name: str):
    """The Python class of ``pkg/msg/Type`` (also ``pkg/srv/Name_Event`` etc.).

    ImportError with what to install when the interface package is missing here.
    """
    package, namespace, name = split_type(type_name)
    try:
        module = importlib.import_module(f'{package}.{namespace}')
        return getattr(module, name)
    except (ImportError, AttributeError):
        raise ImportError(f'message type {type_name} is not installed in this Python '
                          f'environment; install the {package} interface package') from None


def text_param(description: str, ptype=ParameterType.PARAMETER_STRING) -> ParameterDescriptor:
    """A read-only parameter of type `ptype` (default string)."""
    return ParameterDescriptor(type=ptype, description=description, read_only=True)


def int_param(description: str, lo: int, hi: int) -> ParameterDescriptor:
    """A read-only integer parameter in lo..hi."""
    return ParameterDescriptor(type=ParameterType.PARAMETER_INTEGER, description=description,
                               read_only=True,
                               integer_range=[IntegerRange(from_value=lo, to_value=hi, step=1)])


def float_param(description: str, lo: float, hi: float) -> ParameterDescriptor:
    """A read-only floating-point parameter in [lo, hi]."""
    return ParameterDescriptor(type=ParameterType.PARAMETER_DOUBLE, description=description,
                               read_only=True,
                               floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi)])
