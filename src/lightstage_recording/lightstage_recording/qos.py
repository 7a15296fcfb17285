"""QoS profiles as rosbag2 stores them (``offered_qos_profiles``, metadata.yaml version 9).
Pure Python: the rclpy conversion is in `bag_ros`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import yaml

INFINITE_NS = 2 ** 63 - 1  # RMW_DURATION_INFINITE: {sec: 9223372036, nsec: 854775807}

_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all', 3: 'unknown'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort', 3: 'unknown',
                4: 'best_available'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile', 3: 'unknown',
               4: 'best_available'}
_LIVELINESS = {0: 'system_default', 1: 'automatic', 2: 'manual_by_node', 3: 'manual_by_topic',
               4: 'unknown', 5: 'best_available'}


def _policy(value, names: dict[int, str], what: str) -> str:
    if isinstance(value, bool):
        raise ValueError(f'QoS {what} {value!r} is not a policy')
    if isinstance(value, int):
        return names.get(value, 'unknown')
    text = str(value).strip().lower()
    if text not in names.values():
        raise ValueError(f'QoS {what} {value!r} is not one of {sorted(set(names.values()))}')
    return text


def _duration_ns(value) -> int:
    if value is None:
        return INFINITE_NS
    if isinstance(value, int):
        return value
    ns = int(value.get('sec', 0)) * 1_000_000_000 + int(value.get('nsec', 0))
    return min(ns, INFINITE_NS)


def _duration_dict(ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}


@dataclass(frozen=True)
class QosProfile:
    """One publisher's QoS as rosbag2 stores it (policy names of rmw, durations in ns).

    Profiles taken from graph discovery have history ``unknown`` and depth 0: DDS does not
    announce them (rosbag2 records the same).
    """
    history: str = 'keep_last'
    depth: int = 10
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline_ns: int = INFINITE_NS
    lifespan_ns: int = INFINITE_NS
    liveliness: str = 'automatic'
    liveliness_lease_duration_ns: int = INFINITE_NS
    avoid_ros_namespace_conventions: bool = False

    def to_dict(self) -> dict:
        """The rosbag2 version-9 form (policy names as strings, durations as sec/nsec)."""
        return {'history': self.history, 'depth': int(self.depth),
                'reliability': self.reliability, 'durability': self.durability,
                'deadline': _duration_dict(self.deadline_ns),
                'lifespan': _duration_dict(self.lifespan_ns),
                'liveliness': self.liveliness,
                'liveliness_lease_duration': _duration_dict(self.liveliness_lease_duration_ns),
                'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions)}

    @classmethod
    def from_dict(cls, d: dict) -> 'QosProfile':
        """From rosbag2's YAML, version 9 (names) or 8 and older (rmw enum numbers)."""
        return cls(history=_policy(d.get('history', 1), _HISTORY, 'history'),
                   depth=int(d.get('depth', 0)),
                   reliability=_policy(d.get('reliability', 1), _RELIABILITY, 'reliability'),
                   durability=_policy(d.get('durability', 2), _DURABILITY, 'durability'),
                   deadline_ns=_duration_ns(d.get('deadline')),
                   lifespan_ns=_duration_ns(d.get('lifespan')),
                   liveliness=_policy(d.get('liveliness', 1), _LIVELINESS, 'liveliness'),
                   liveliness_lease_duration_ns=_duration_ns(d.get('liveliness_lease_duration')),
                   avoid_ros_namespace_conventions=bool(d.get('avoid_ros_namespace_conventions',
                                                              False)))


def dump_qos_profiles(profiles: Iterable[QosProfile]) -> str:
    """The ``offered_qos_profiles`` YAML string of an MCAP channel ('' for none)."""
    items = [p.to_dict() for p in profiles]
    return yaml.safe_dump(items, sort_keys=False).strip() if items else ''


def parse_qos_profiles(value) -> list[QosProfile]:
    """``offered_qos_profiles`` from a channel (YAML string) or metadata.yaml (list)."""
    if value is None or value == '':
        return []
    items = yaml.safe_load(value) if isinstance(value, str) else value
    if not items:
        return []
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise ValueError(f'offered_qos_profiles is not a list of QoS mappings: {value!r:.200}')
    return [QosProfile.from_dict(i) for i in items]
