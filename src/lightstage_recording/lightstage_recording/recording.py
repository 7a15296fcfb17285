"""What to record and how to subscribe / publish: topic selection, QoS choice, and the
recorder's bag (`Recording`: writing, and stopping cleanly when the disk fails). No rclpy.

The recorder and the player map these onto rclpy (`bag_ros`); the rules are here so they
can be tested without a graph.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, replace
from typing import Iterable, Sequence

from .exceptions import BagWriteError
from .formatting import format_size
from .losses import LossCounter
from .msg_definitions import is_service_event
from .qos import INFINITE_NS, QosProfile
from .writer import BagWriter

# what `lightstage play` leaves out unless --topics names it: service events (replaying them
# would pose as calls the live services never served), and the log / parameter topics every
# node has (replaying them into a live graph only confuses it)
DEFAULT_PLAY_EXCLUDE = r'/_service_event$|^/rosout$|^/parameter_events$'


def is_hidden(topic: str) -> bool:
    """A topic with a name part starting with ``_`` (ROS's convention for hidden topics)."""
    return any(part.startswith('_') for part in topic.split('/') if part)


def compile_regex(pattern: str, what: str) -> re.Pattern | None:
    """A compiled pattern, None for '', or ValueError naming the parameter and the problem."""
    if not pattern:
        return None
    try:
        return re.compile(pattern)
    except re.error as exc:
        raise ValueError(f'{what} {pattern!r} is not a valid regular expression ({exc}); '
                         'quote it for the shell and check brackets and escapes') from None


@dataclass(frozen=True)
class TopicSelector:
    """Which topics a recorder takes, like ``ros2 bag record``.

    ``topics``: exact names (None = every topic); ``include``: regular expression a name
    must match (``re.search``; with ``topics`` a topic is taken if either selects it);
    ``exclude``: names matching it are left out. Service event topics
    (``<service>/_service_event``) are taken with ``services`` unless excluded; other hidden
    topics (a name part starting with ``_``, e.g. actions' ``_action/feedback``) only with
    ``hidden``.
    """
    topics: tuple | None = None
    include: str = ''
    exclude: str = ''
    services: bool = True
    hidden: bool = False

    def __post_init__(self):
        compile_regex(self.include, 'include_regex')
        compile_regex(self.exclude, 'exclude_regex')
        for t in self.topics or ():
            if not t.startswith('/'):
                raise ValueError(f'topic {t!r} is not a full name; give it with its leading / '
                                 f'(e.g. /{t})')

    def wants(self, topic: str, type_name: str) -> bool:
        include, exclude = compile_regex(self.include, ''), compile_regex(self.exclude, '')
        if exclude is not None and exclude.search(topic):
            return False
        if self.topics is not None or include is not None:
            named = self.topics is not None and topic in self.topics
            matched = include is not None and include.search(topic) is not None
            if not (named or matched):
                return False
            if named:
                return True  # asked for by name: taken even if hidden
        if is_service_event(topic, type_name):
            return self.services
        if is_hidden(topic):
            return self.hidden
        return True


def subscription_qos(offered: Sequence[QosProfile], depth: int) -> QosProfile:
    """The QoS a recorder asks for, given what the topic's publishers offer.

    Reliable only if every publisher is reliable (a reliable reader does not match a
    best-effort writer), transient-local only if every publisher is (so late-joining
    recorders get latched data), keep-last ``depth`` (DDS does not announce history).
    """
    offered = list(offered)
    reliable = bool(offered) and all(q.reliability == 'reliable' for q in offered)
    latched = bool(offered) and all(q.durability == 'transient_local' for q in offered)
    return QosProfile(history='keep_last', depth=int(depth),
                      reliability='reliable' if reliable else 'best_effort',
                      durability='transient_local' if latched else 'volatile')


def playback_qos(offered: Sequence[QosProfile], depth: int) -> QosProfile:
    """The QoS a player publishes a recorded topic with: the recorded publishers' (the first
    one's deadline/lifespan/liveliness), made reliable / transient-local only if all were;
    keep-last with the recorded depth, or ``depth`` where discovery did not tell it."""
    offered = list(offered)
    if not offered:
        return QosProfile(history='keep_last', depth=int(depth))
    first = offered[0]
    known_depth = max((q.depth for q in offered if q.history == 'keep_last'), default=0)
    reliable = all(q.reliability == 'reliable' for q in offered)
    latched = all(q.durability == 'transient_local' for q in offered)
    return replace(first, history='keep_last', depth=int(known_depth or depth),
                   reliability='reliable' if reliable else 'best_effort',
                   durability='transient_local' if latched else 'volatile',
                   liveliness=first.liveliness if first.liveliness in ('automatic', 'manual_by_topic')
                   else 'automatic',
                   deadline_ns=first.deadline_ns if first.deadline_ns > 0 else INFINITE_NS,
                   lifespan_ns=first.lifespan_ns if first.lifespan_ns > 0 else INFINITE_NS)


def select_play_topics(available: Iterable[str], topics: Sequence[str] | None,
                       exclude: str = DEFAULT_PLAY_EXCLUDE) -> list[str]:
    """Topics to play: the named ones (ValueError for names the bag does not hold) or every
    recorded topic not matching ``exclude``."""
    available = list(available)
    if topics:
        unknown = [t for t in topics if t not in available]
        if unknown:
            raise ValueError(f'the bag has no topic {", ".join(unknown)}; it has: '
                             f'{", ".join(sorted(available)) or "(none)"}')
        return [t for t in available if t in topics]
    pattern = compile_regex(exclude, 'exclude_regex')
    return [t for t in available if pattern is None or not pattern.search(t)]


def playback_delay_s(log_time_ns: int, first_ns: int, rate: float) -> float:
    """Seconds after the start of playback at which a message recorded at log_time_ns goes out."""
    return max(0, log_time_ns - first_ns) / 1e9 / rate


class Recording:
    """The recorder's bag: what the recorder node's callbacks and timers do with it, without
    rclpy.

    `add_topic`, `receive` (one raw message with rclpy's message info) and `flush` return
    False once the recording has stopped. The first write error (disk full, I/O error) stops
    it: `error` says what happened, what the bag holds and what to do; what arrives after
    that is counted in `dropped`, not written; `close` still finishes the bag for the
    messages in it (metadata.yaml, as far as the disk allows; the file in progress ends after
    its last complete chunk, for `lightstage bag recover` to complete).

    `losses` counts what never arrived (`losses.LossCounter`: publisher sequence gaps,
    service requests without response); `report` says it.
    """

    def __init__(self, writer: BagWriter):
        self.writer = writer
        self.dropped = 0
        self.losses = LossCounter()

    @property
    def error(self) -> str:
        return self.writer.error

    @property
    def stopped(self) -> bool:
        return bool(self.writer.error) or self.writer.closed

    def add_topic(self, name: str, type_name: str, offered_qos=(), **kwargs) -> bool:
        if self.stopped:
            return False
        try:
            self.writer.add_topic(name, type_name, offered_qos, **kwargs)
        except BagWriteError:
            return False
        self.losses.add_topic(name, type_name, len(list(offered_qos)))
        return True

    def receive(self, topic: str, data: bytes, info: dict) -> bool:
        """One message as a raw subscription gets it: log time = received_timestamp, publish
        time = source_timestamp (ns), the publisher's sequence number."""
        if self.stopped:
            self.dropped += 1
            return False
        received = info.get('received_timestamp') or time.time_ns()
        sent = info.get('source_timestamp') or received
        sequence = info.get('publication_sequence_number') or None
        try:
            self.writer.write(topic, data, received, sent, sequence)
        except BagWriteError:
            self.dropped += 1
            return False
        self.losses.message(topic, sequence or 0, data)
        return True

    def flush(self) -> bool:
        if self.stopped:
            return False
        try:
            self.writer.flush()
        except BagWriteError:
            return False
        return True

    def close(self) -> str:
        """Finish the bag (idempotent); the error that stopped the recording, or ''."""
        self.writer.close()
        return self.error

    def report(self, seconds: float, selector: TopicSelector | None = None,
               skipped: dict | None = None) -> str:
        """What was recorded, per topic; first, if the recording stopped on an error, that."""
        w = self.writer
        topics = w.topics
        services = [t for t in topics.values() if t.is_service_event]
        lines = []
        if self.error:
            lines.append(f'RECORDING STOPPED: {self.error}')
        lines.append(f'recorded {w.message_count} messages on {len(topics) - len(services)} '
                     f'topics and {len(services)} service event topics in {seconds:.1f} s into '
                     f'{w.path} ({format_size(w.size_bytes)}'
                     + (f' in {len(w.files)} files' if len(w.files) > 1 else '') + ')')
        if w.deleted_files:
            lines.append(f'  not kept: {w.custom_data["deleted_files"]}')
        for t in sorted(topics.values(), key=lambda t: t.name):
            lines.append(f'  {t.name}: {t.count} ({t.type})')
        if self.error:
            n = self.dropped
            lines.append(f'  not recorded: the chunk in progress at the error and the {n} '
                         f'message{"s" if n != 1 else ""} that arrived from then on')
        if selector is not None and selector.topics:
            never = [t for t in selector.topics if t not in topics]
            if never:
                lines.append(f'  never published while recording: {", ".join(never)}')
        for topic, why in sorted((skipped or {}).items()):
            lines.append(f'  not recorded: {topic}: {why}')
        lost = self.losses.lines()
        if lost:
            lines.append('  LOST WHILE RECORDING (sent by the graph, not in the bag: the recorder '
                         'was stopped or too slow):')
            lines.extend(f'    {text}' for text in lost)
        lines.extend(f'  warning: {text}' for text in w.warnings)
        lines.append(f'  `lightstage bag info {w.path}` summarises it; `lightstage play {w.path}` '
                     'replays it')
        return '\n'.join(lines)
