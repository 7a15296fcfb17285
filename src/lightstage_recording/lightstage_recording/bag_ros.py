"""rclpy side of recording and replay: QoS conversion and message classes by type name."""
from __future__ import annotations

import importlib

from rclpy.duration import Duration
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile,
                       ReliabilityPolicy)

from .msg_definitions import split_type
from .qos import INFINITE_NS, QosProfile


def _name(enum, value) -> str:
    """A policy as rosbag2 names it (rclpy's short key: 'keep_last', 'best_effort', ...)."""
    try:
        return enum(value).short_key
    except ValueError:
        return 'unknown'


def _ns(duration) -> int:
    ns = int(duration.nanoseconds)
    return INFINITE_NS if ns >= INFINITE_NS or ns < 0 else ns


def from_rclpy_qos(q: QoSProfile) -> QosProfile:
    """An rclpy profile (e.g. a discovered publisher's) as rosbag2 stores it."""
    return QosProfile(history=_name(HistoryPolicy, q.history), depth=int(q.depth),
                      reliability=_name(ReliabilityPolicy, q.reliability),
                      durability=_name(DurabilityPolicy, q.durability),
                      deadline_ns=_ns(q.deadline), lifespan_ns=_ns(q.lifespan),
                      liveliness=_name(LivelinessPolicy, q.liveliness),
                      liveliness_lease_duration_ns=_ns(q.liveliness_lease_duration),
                      avoid_ros_namespace_conventions=bool(q.avoid_ros_namespace_conventions))


def _duration(ns: int) -> Duration:
    return Duration(nanoseconds=0) if ns >= INFINITE_NS else Duration(nanoseconds=int(ns))


def _policy(enum, name: str, default):
    """The policy named `name` (a short key), `default` for an unknown one."""
    try:
        value = enum[str(name).upper()]
    except KeyError:
        return default
    return default if value.name == 'UNKNOWN' else value


def to_rclpy_qos(q: QosProfile) -> QoSProfile:
    """A profile for a subscription or publisher (infinite durations as rclpy's default 0;
    unknown policies as keep-last / reliable / volatile / automatic)."""
    history = _policy(HistoryPolicy, q.history, HistoryPolicy.KEEP_LAST)
    if history == HistoryPolicy.SYSTEM_DEFAULT:
        history = HistoryPolicy.KEEP_LAST
    return QoSProfile(
        history=history, depth=max(1, int(q.depth)),
        reliability=_policy(ReliabilityPolicy, q.reliability, ReliabilityPolicy.RELIABLE),
        durability=_policy(DurabilityPolicy, q.durability, DurabilityPolicy.VOLATILE),
        liveliness=_policy(LivelinessPolicy, q.liveliness, LivelinessPolicy.AUTOMATIC),
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


def new_published_topics(node, known, selector):
    """The topics of the graph a recorder-like node should take up now, for each one
    `(topic, type_name, message class, publishers, problem)`: topics in `known` are passed
    over, as are those `selector` does not want and those nobody publishes yet (discovery
    looks again later); `problem` is why a topic cannot be taken (several types, no message
    class installed), else ''."""
    for topic, types in node.get_topic_names_and_types():
        if topic in known:
            continue
        if len(types) != 1:
            yield topic, '', None, [], f'it has {len(types)} types ({", ".join(types)}); one is needed'
            continue
        type_name = types[0]
        if not selector.wants(topic, type_name):
            continue
        publishers = node.get_publishers_info_by_topic(topic)
        if not publishers:
            continue
        try:
            yield topic, type_name, message_class(type_name), publishers, ''
        except ImportError as exc:
            yield topic, type_name, None, publishers, str(exc)
