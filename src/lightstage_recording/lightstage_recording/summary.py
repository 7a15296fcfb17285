"""What a bag holds: its topics, its summary (`BagInfo`) and its messages (`BagMessage`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lightstage_graph.names import SERVICE_EVENT_SUFFIX

from . import msg_definitions


@dataclass
class TopicInfo:
    """One topic of a bag."""
    name: str
    type: str
    count: int = 0
    serialization_format: str = 'cdr'
    offered_qos: list = field(default_factory=list)
    type_hash: str = ''
    schema_encoding: str = ''
    schema_text: str = ''

    @property
    def is_service_event(self) -> bool:
        return msg_definitions.is_service_event(self.name, self.type)

    @property
    def service_name(self) -> str:
        return self.name[:-len(SERVICE_EVENT_SUFFIX)] if self.is_service_event else ''

    @property
    def service_type(self) -> str:
        return self.type[:-len('_Event')] if self.is_service_event else ''


@dataclass
class BagInfo:
    """What a bag holds. ``complete`` is False when the file has no intact summary/footer
    (writer killed) or damaged parts; ``problems`` says what and where."""
    path: Path
    files: list
    size_bytes: int
    start_ns: int
    end_ns: int
    message_count: int
    topics: dict
    complete: bool
    problems: list = field(default_factory=list)
    ros_distro: str = ''
    library: str = ''
    has_metadata_yaml: bool = False
    storage_identifier: str = 'mcap'
    custom_data: dict = field(default_factory=dict)  # metadata.yaml's (e.g. of a recovery)
    verified: bool = False        # every chunk was read back (CRCs checked where they have one)
    chunks: int = 0               # chunks read back
    chunks_without_crc: int = 0   # of those, chunks that carry no CRC (rosbag2's default)
    losses: object = None         # losses.LossCounter of the messages read back (None: not read)

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0

    def to_json(self) -> dict:
        return {'path': str(self.path), 'files': [str(f) for f in self.files],
                'size_bytes': self.size_bytes, 'storage_identifier': self.storage_identifier,
                'ros_distro': self.ros_distro, 'start_ns': self.start_ns, 'end_ns': self.end_ns,
                'duration_ns': self.duration_ns, 'message_count': self.message_count,
                'complete': self.complete, 'problems': list(self.problems),
                'custom_data': dict(self.custom_data), 'verified': self.verified,
                'chunks_checked': self.chunks, 'chunks_without_crc': self.chunks_without_crc,
                'lost_while_recording': self.losses.to_json() if self.losses is not None else None,
                'topics': [{'name': t.name, 'type': t.type, 'count': t.count,
                            'serialization_format': t.serialization_format,
                            'type_hash': t.type_hash,
                            'offered_qos_profiles': [q.to_dict() for q in t.offered_qos]}
                           for t in self.topics.values()]}


@dataclass(frozen=True)
class BagMessage:
    """One recorded message: the CDR bytes as received and its times (ns since the epoch)."""
    topic: str
    type: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int
    sequence: int = 0
