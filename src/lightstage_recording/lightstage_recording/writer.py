"""rosbag2-compatible MCAP bags: write, read, summarise, recover. Pure Python, no rclpy.

A bag is a directory ``NAME/`` holding ``NAME_0.mcap`` (split by size or duration:
``NAME_0.mcap``, ``NAME_1.mcap``, ..., each a complete MCAP file) and ``metadata.yaml``
listing every file, as ``ros2 bag record -s mcap`` (Jazzy) writes it:

- the MCAP header has profile ``ros2``;
- one schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, the ``.msg``
  text with its dependencies (`msg_definitions.full_definition`);
- one channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (the
  publishers' QoS as rosbag2 version-9 YAML) and ``topic_type_hash`` (``RIHS01_...``);
- every message: the serialized CDR bytes as received, ``log_time`` = receive time,
  ``publish_time`` = send time (ns since the epoch);
- a metadata record ``rosbag2`` (``serialized_metadata``, ``ROS_DISTRO``) and the
  ``metadata.yaml`` (top key ``rosbag2_bagfile_information``, version 9) written when the bag
  is closed.

Writing: `BagWriter.flush` hands the chunk in progress to the OS (no fsync); `close` fsyncs
the file, metadata.yaml and the directory. A write error (disk full) stops the writer: the
file is cut back to its last complete chunk and closed with a summary and metadata.yaml
listing exactly what it holds, as far as the disk allows (`BagWriteError`, `BagWriter.error`).

Reading walks the files record by record, so a bag whose writer was killed (no summary, no
footer, no metadata.yaml) or whose file is damaged still yields every intact message; what
was wrong is in ``BagInfo.problems`` / ``BagReader.problems``, and `recover_bag` writes a
complete copy of the intact part and says what was lost. Files that cannot be read at all
raise `BagError`, whose message says what was wrong and what to do.
"""
from __future__ import annotations

import datetime as _dt
import errno
import heapq
import io
import itertools
import os
import re
import struct
import threading
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

import yaml

from . import msg_definitions

MCAP_MAGIC = b'\x89MCAP0\r\n'
ROS_DISTRO = 'jazzy'
METADATA_FILE = 'metadata.yaml'
METADATA_VERSION = 9
INFINITE_NS = 2 ** 63 - 1  # RMW_DURATION_INFINITE: {sec: 9223372036, nsec: 854775807}
COMPRESSIONS = ('lz4', 'none')


class BagError(Exception):
    """A bag that cannot be written or read; the message says what was wrong and what to do."""


# --------------------------------------------------------------------------- QoS

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


# --------------------------------------------------------------------------- summary types


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
        return self.name[:-len(msg_definitions.SERVICE_EVENT_SUFFIX)] if self.is_service_event else ''

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


# --------------------------------------------------------------------------- writer


class BagWriteError(BagError):
    """Writing a bag failed (disk full, I/O error) and the writer stopped. The bag holds what
    was written before; the message says what happened, what the bag holds and what to do."""


def default_bag_name(now: _dt.datetime | None = None) -> str:
    """``rosbag2_YYYY_MM_DD-HH_MM_SS`` (local time), the name ``ros2 bag record`` picks."""
    now = now or _dt.datetime.now()
    return now.strftime('rosbag2_%Y_%m_%d-%H_%M_%S')


def check_output_dir(path) -> None:
    """BagError unless ``path`` can become a new bag directory: it must not exist, or be an
    empty directory (``ros2 bag record`` refuses any existing directory; an empty one -- made
    by ``mkdir``, a fresh mount -- is accepted here). A bag is never overwritten."""
    path = Path(path)
    if not path.exists():
        return
    if not path.is_dir():
        raise BagError(f'{path} already exists and is not a directory; give a new bag directory '
                       '(it must not exist, or be an empty directory)')
    if any(path.iterdir()):
        raise BagError(f'{path} already exists and is not empty; choose another output directory '
                       'or delete it (a bag is never overwritten; an existing empty directory is '
                       'used)')


def _write_all(fd: int, data) -> None:
    """Hand all of ``data`` to the OS (``os.write`` until done). Every byte the writer puts in
    a bag file or metadata.yaml goes through here."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _write_error_text(exc: OSError, path: Path, held: str, retry: str) -> str:
    """What a write error means for the bag at ``path``, what it holds, what to do."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f'disk full writing {path}: {exc.strerror}; {held}; free space and {retry}'
    return f'cannot write {path}: {exc.strerror or exc}; {held}; check the disk and {retry}'


def _fsync_dir(path: Path) -> None:
    """fsync a directory, so that the names created in it survive a power loss. Best effort:
    some file systems refuse to fsync directories."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class _Sink:
    """The MCAP file as the mcap writer's output stream, unbuffered: each write goes to the OS
    at once, so the file always ends where the writer's last completed call left it, and
    `cut` can take it back to such a point."""

    def __init__(self, path: Path):
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_CLOEXEC', 0),
                          0o666)
        self.pos = 0

    def write(self, data) -> int:
        _write_all(self.fd, data)
        self.pos += len(data)
        return len(data)

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass  # nothing is buffered here

    def cut(self, size: int) -> None:
        os.ftruncate(self.fd, size)
        os.lseek(self.fd, size, os.SEEK_SET)
        self.pos = size


def _index_data_section(path: Path, end: int) -> tuple[list, dict[int, int]]:
    """The chunk indexes and per-channel message counts of the records of an MCAP file from
    its magic to byte ``end`` (a record boundary), read from the chunk headers and message
    indexes without decompressing anything."""
    from mcap.opcode import Opcode
    from mcap.records import ChunkIndex

    chunks: list = []
    counts: dict[int, int] = {}
    with open(path, 'rb') as f:
        offset = len(MCAP_MAGIC)
        current = None
        while offset + 9 <= end:
            f.seek(offset)
            opcode, length = struct.unpack('<BQ', f.read(9))
            if offset + 9 + length > end:
                break
            if opcode == Opcode.CHUNK:
                start_ns, end_ns, uncompressed, _crc, n = struct.unpack('<QQQII', f.read(32))
                compression = f.read(n).decode()
                (compressed,) = struct.unpack('<Q', f.read(8))
                current = ChunkIndex(message_start_time=start_ns, message_end_time=end_ns,
                                     chunk_start_offset=offset, chunk_length=9 + length,
                                     message_index_offsets={}, message_index_length=0,
                                     compression=compression, compressed_size=compressed,
                                     uncompressed_size=uncompressed)
                chunks.append(current)
            elif opcode == Opcode.MESSAGE_INDEX and current is not None:
                channel_id, size = struct.unpack('<HI', f.read(6))
                current.message_index_offsets[channel_id] = offset
                current.message_index_length += 9 + length
                counts[channel_id] = counts.get(channel_id, 0) + size // 16
            else:
                current = None
            offset += 9 + length
    return chunks, counts


@dataclass
class _Topic:
    channel_id: int
    info: TopicInfo
    qos_yaml: str


@dataclass
class _FileStats:
    """What one file of a bag being written holds (message counts by channel id, log times)."""
    path: Path
    count: int = 0
    start_ns: int | None = None
    end_ns: int | None = None
    per_channel: dict = field(default_factory=dict)

    def add(self, channel_id: int, log_time_ns: int) -> None:
        self.count += 1
        self.per_channel[channel_id] = self.per_channel.get(channel_id, 0) + 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)

    def to_metadata(self) -> dict:
        """Its entry of metadata.yaml's ``files``."""
        return {'path': self.path.name,
                'starting_time': {'nanoseconds_since_epoch': int(self.start_ns or 0)},
                'duration': {'nanoseconds': int((self.end_ns - self.start_ns) if self.count else 0)},
                'message_count': int(self.count)}


MIN_SPLIT_SIZE_BYTES = 1024  # rosbag2's MCAP storage refuses smaller max_bag_size too


class BagWriter:
    """Write a bag directory. Thread-safe; `close` (or the context manager) finishes it.

    ``compression``: ``lz4`` (per chunk) or ``none``. ``chunk_size_bytes``: messages are
    grouped in chunks of about this size; call `flush` regularly so that a writer killed
    without closing loses at most the chunk in progress (the recorder flushes every second).
    `flush` hands the chunk to the OS (``write``), it does not ``fsync``; `close` fsyncs the
    MCAP file, ``metadata.yaml`` and the directory.

    Splitting, as ``ros2 bag record --max-bag-size / --max-bag-duration`` does: with
    ``max_bag_size_bytes`` the file in progress is closed (summary, footer, fsync) before the
    message that would take it to that size (counting the chunk in progress uncompressed), with
    ``max_bag_duration_s`` before the first message logged that long after the file's first;
    the next goes to ``NAME_1.mcap``, ``NAME_2.mcap``, ... Each file is a complete MCAP file
    with every schema and channel. ``max_bag_files`` (0: all) keeps only the newest that many:
    older files are deleted as new ones start, and ``metadata.yaml`` (``custom_data``) says
    how many files and messages were deleted. `events` (and ``on_event``) tell each split and
    deletion.

    Write errors (disk full, I/O error): the call that hit one raises `BagWriteError`; the
    file is cut back to the end of the last complete chunk and the writer takes nothing more.
    The counts (`message_count`, `topics`) then are those of the messages in the files, and
    `close` still writes what it can: a summary and footer for them, then ``metadata.yaml``.
    `error` keeps the message ('' while all is well); `close` does not raise, the context
    manager does (`BagWriteError`) if an error was not raised before. ``retry``: what to do
    again once the disk is fixed, for the messages.
    """

    def __init__(self, path, *, compression: str = 'lz4', chunk_size_bytes: int = 1 << 20,
                 library: str = 'lightstage_bringup', ros_distro: str = ROS_DISTRO,
                 custom_data: dict | None = None, retry: str = 'record again',
                 max_bag_size_bytes: int = 0, max_bag_duration_s: float = 0.0,
                 max_bag_files: int = 0, on_event=None):
        if compression not in COMPRESSIONS:
            raise BagError(f'compression {compression!r} is not supported; use one of '
                           f'{", ".join(COMPRESSIONS)}')
        if chunk_size_bytes < 1024:
            raise BagError(f'chunk size {chunk_size_bytes} B is too small; use at least 1024 B')
        if max_bag_size_bytes and not MIN_SPLIT_SIZE_BYTES <= max_bag_size_bytes:
            raise BagError(f'max_bag_size_bytes {max_bag_size_bytes} is too small; use 0 (no '
                           f'splitting by size) or at least {MIN_SPLIT_SIZE_BYTES}')
        if max_bag_size_bytes < 0 or not 0 <= max_bag_duration_s < float('inf') or max_bag_files < 0:
            raise BagError(f'max_bag_size_bytes ({max_bag_size_bytes}), max_bag_duration_s '
                           f'({max_bag_duration_s}) and max_bag_files ({max_bag_files}) must be '
                           '>= 0 (0: no limit) and finite')
        self.path = Path(path)
        check_output_dir(self.path)
        self.created_dir = not self.path.exists()
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagError(f'cannot create the bag directory {self.path}: {exc.strerror}; choose '
                           'a writable location') from None
        self.compression = compression
        self.chunk_size_bytes = int(chunk_size_bytes)
        self.max_bag_size_bytes = int(max_bag_size_bytes)
        self.max_bag_duration_ns = int(max_bag_duration_s * 1e9)
        self.max_bag_files = int(max_bag_files)
        self.on_event = on_event
        self.ros_distro = ros_distro
        self.custom_data: dict[str, str] = dict(custom_data or {})
        self.retry = retry
        try:
            from importlib.metadata import version
            mcap_version = version('mcap')
        except Exception:  # noqa: BLE001 - only decorates the library string
            mcap_version = '?'
        self._library = f'{library}; mcap-python {mcap_version}'
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._schema_records: dict = {}   # id -> mcap Schema: for each new file and a summary
        self._channel_records: dict = {}  # id -> mcap Channel   written after an error
        self._topics: dict[str, _Topic] = {}
        self._sequence: dict[str, itertools.count] = {}
        self._files: list[_FileStats] = []     # the files the bag holds, the one in progress last
        self.deleted_files: list[_FileStats] = []  # deleted to keep max_bag_files
        self.events: list[str] = []           # splits and deletions, as told to on_event
        self._sink = None
        self._writer = None
        self.bytes_written = 0
        self.warnings: list[str] = []
        self.error = ''
        self.closed = False
        try:
            self._open_file()
        except OSError as exc:
            self._discard()
            raise BagWriteError(_write_error_text(exc, self.path, 'nothing was written',
                                                  self.retry)) from None

    # -- files
    def _open_file(self) -> None:
        """Start the next file (``NAME_<i>.mcap``) with every schema and channel known so far."""
        from mcap.writer import CompressionType, Writer

        index = len(self._files) + len(self.deleted_files)
        self.file_path = self.path / f'{self.path.name}_{index}.mcap'
        self._sink = _Sink(self.file_path)
        self._files.append(_FileStats(self.file_path))
        kind = CompressionType.LZ4 if self.compression == 'lz4' else CompressionType.NONE
        writer = Writer(self._sink, chunk_size=self.chunk_size_bytes, compression=kind)
        writer.start(profile='ros2', library=self._library)
        # the same ids in every file: registered again in the order they were first
        for schema_id, s in self._schema_records.items():
            if writer.register_schema(s.name, s.encoding, s.data) != schema_id:
                raise AssertionError('schema ids differ between the files of a bag')
        for channel_id, c in self._channel_records.items():
            if writer.register_channel(c.topic, c.message_encoding, c.schema_id, c.metadata) != channel_id:
                raise AssertionError('channel ids differ between the files of a bag')
        self._writer = writer
        self._unchunked = 0           # bytes added since the file last grew: the chunk in progress
        self._file_size_seen = self._sink.pos
        self._chunk_indexes: list = []    # after an error: those of the chunks in the file
        self._torn = False                # after an error the file could not be cut back
        self._unread = False              # ... or read back: its counts are not known
        self.summary_written = False
        self.metadata_written = False

    @property
    def files(self) -> list[Path]:
        """The files the bag holds now, oldest first."""
        return [f.path for f in self._files]

    @property
    def size_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.files if p.exists())

    @property
    def message_count(self) -> int:
        return sum(f.count for f in self._files)

    @property
    def start_ns(self) -> int | None:
        return min((f.start_ns for f in self._files if f.count), default=None)

    @property
    def end_ns(self) -> int | None:
        return max((f.end_ns for f in self._files if f.count), default=None)

    def _sync_topic_counts(self) -> None:
        for t in self._topics.values():
            t.info.count = sum(f.per_channel.get(t.channel_id, 0) for f in self._files)

    def _event(self, text: str) -> None:
        self.events.append(text)
        if self.on_event is not None:
            self.on_event(text)

    def _split_reason(self, log_time_ns: int, size: int) -> str:
        """Why the file in progress must end before a message (''; it need not)."""
        current = self._files[-1]
        if not current.count:
            return ''  # every file gets at least one message
        if self._sink.pos != self._file_size_seen:  # a chunk went out: it is in the file size
            self._file_size_seen, self._unchunked = self._sink.pos, 0
        if self.max_bag_size_bytes and (self._sink.pos + self._unchunked + size
                                        >= self.max_bag_size_bytes):
            return f'max_bag_size_bytes {self.max_bag_size_bytes} reached'
        if self.max_bag_duration_ns and log_time_ns - current.start_ns >= self.max_bag_duration_ns:
            return f'max_bag_duration_s {self.max_bag_duration_ns / 1e9:g} reached'
        return ''

    def _split(self, why: str) -> None:
        """Close the file in progress completely, start the next, delete the oldest beyond
        max_bag_files. OSError: the writer stops (`_fail`), as for any write error."""
        done = self._files[-1]
        mark = self._sink.pos
        try:
            self._writer.add_metadata('rosbag2', self._rosbag2_record())
            self._writer.finish()
        except OSError as exc:
            self._fail(exc, mark)
            raise BagWriteError(self.error) from exc
        self.summary_written = True
        self._close_fd()
        try:
            self._open_file()
        except OSError as exc:
            failed = self._files.pop()
            if self._sink is not None:
                os.close(self._sink.fd)
                self._sink = None
                failed.path.unlink(missing_ok=True)
            self._writer = None
            self.file_path = done.path
            held = (f'the bag holds everything up to {format_time(self.end_ns)} in its '
                    f'{len(self._files)} complete file{"s" if len(self._files) > 1 else ""}: '
                    f'{self.message_count} messages')
            self.error = _write_error_text(exc, failed.path, held, self.retry)
            raise BagWriteError(self.error) from exc
        self._event(f'{done.path.name} closed ({done.count} messages, '
                    f'{format_size(done.path.stat().st_size)}; {why}); now writing '
                    f'{self.file_path.name}')
        while self.max_bag_files and len(self._files) > self.max_bag_files:
            oldest = self._files[0]
            try:
                oldest.path.unlink()
            except OSError as exc:
                self.warnings.append(f'could not delete {oldest.path.name} to keep max_bag_files '
                                     f'{self.max_bag_files}: {exc.strerror}')
                break
            self.deleted_files.append(self._files.pop(0))
            self._sync_topic_counts()
            gone = self.deleted_files
            self.custom_data['deleted_files'] = (
                f'{len(gone)} oldest files ({gone[0].path.name} .. {gone[-1].path.name}, '
                f'{sum(f.count for f in gone)} messages logged from {format_time(gone[0].start_ns)} '
                f'to {format_time(gone[-1].end_ns)}) were deleted to keep max_bag_files '
                f'{self.max_bag_files}')
            self._event(f'{oldest.path.name} deleted ({oldest.count} messages) to keep '
                        f'max_bag_files {self.max_bag_files}')

    def _close_fd(self) -> None:
        try:
            os.fsync(self._sink.fd)
        except OSError as exc:
            self._note(f'fsync of {self.file_path.name} failed ({exc.strerror}): what the OS '
                       'has not written back is lost if the power fails')
        os.close(self._sink.fd)
        self._sink = None

    def _discard(self) -> None:
        """Remove what this writer created (a failed constructor; a recovery that found
        nothing)."""
        if self._sink is not None and not self.closed:
            os.close(self._sink.fd)
            self._sink = None
        for name in self.files + [self.path / METADATA_FILE, self.path / (METADATA_FILE + '.tmp')]:
            name.unlink(missing_ok=True)
        if self.created_dir:
            try:
                self.path.rmdir()
            except OSError:
                pass

    # -- topics
    def add_topic(self, name: str, type_name: str, offered_qos=(), *, type_hash: str | None = None,
                  schema: tuple[str, str] | None = None, serialization_format: str = 'cdr') -> TopicInfo:
        """Register a topic before its first message (again with the same type: no-op).

        ``offered_qos``: QosProfile list (or an already dumped YAML string).
        ``schema``: (encoding, text) to store instead of the installed definition.
        """
        from mcap.records import Channel, Schema

        with self._lock:
            self._check_writable()
            known = self._topics.get(name)
            if known is not None:
                if known.info.type != type_name:
                    raise BagError(f'topic {name} is already recorded with type {known.info.type}, '
                                   f'not {type_name}; one bag topic has one type')
                return known.info
            if type_name not in self._schemas:
                if schema is None:
                    try:
                        schema = ('ros2msg', msg_definitions.full_definition(type_name))
                    except (msg_definitions.DefinitionNotFoundError, ValueError) as exc:
                        self.warnings.append(f'{name}: recorded without a schema: {exc}')
                        schema = ('', '')
                encoding, text = schema
                schema_id = 0
                if encoding or text:
                    schema_id = self._io(self._writer.register_schema, type_name, encoding,
                                         text.encode())
                    self._schema_records[schema_id] = Schema(id=schema_id, data=text.encode(),
                                                             encoding=encoding, name=type_name)
                self._schemas[type_name] = schema_id
            if isinstance(offered_qos, str):
                qos_yaml = offered_qos
                qos_list = parse_qos_profiles(offered_qos)
            else:
                qos_list = list(offered_qos)
                qos_yaml = dump_qos_profiles(qos_list)
            if type_hash is None:
                type_hash = msg_definitions.type_hash(type_name)
            metadata = {'offered_qos_profiles': qos_yaml, 'topic_type_hash': type_hash or ''}
            channel_id = self._io(self._writer.register_channel, name, serialization_format,
                                  self._schemas[type_name], metadata)
            self._channel_records[channel_id] = Channel(
                id=channel_id, topic=name, message_encoding=serialization_format,
                schema_id=self._schemas[type_name], metadata=metadata)
            info = TopicInfo(name, type_name, 0, serialization_format, qos_list, type_hash or '')
            self._topics[name] = _Topic(channel_id, info, qos_yaml)
            self._sequence[name] = itertools.count(1)
            return info

    @property
    def topics(self) -> dict[str, TopicInfo]:
        return {n: t.info for n, t in self._topics.items()}

    # -- messages
    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int | None = None) -> None:
        """Add one serialized message of a registered topic (`BagWriteError`: the disk failed,
        the writer stopped; see the class). Starts the next file first when a split limit is
        reached."""
        with self._lock:
            self._check_writable()
            t = self._topics.get(topic)
            if t is None:
                raise BagError(f'topic {topic} was not added to the bag; call add_topic first')
            log_time_ns = int(log_time_ns)
            data = bytes(data)
            why = self._split_reason(log_time_ns, len(data))
            if why:
                self._split(why)
            seq = next(self._sequence[topic]) if sequence is None else int(sequence) & 0xFFFFFFFF
            self._io(self._writer.add_message, t.channel_id, log_time_ns, data,
                     int(publish_time_ns if publish_time_ns is not None else log_time_ns), seq)
            self._unchunked += len(data) + 31  # + the message record's header
            t.info.count += 1
            self._files[-1].add(t.channel_id, log_time_ns)
            self.bytes_written += len(data)

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the OS (no fsync: it survives the
        process being killed, not a power loss before the OS writes it back)."""
        with self._lock:
            if self.closed:
                return
            self._check_writable()
            self._io(self._writer.flush)

    # -- errors
    def _io(self, call, *args):
        """One call of the mcap writer. Each call leaves whole records in the file; on an
        OSError the file is cut back to where the call started and the writer stops."""
        mark = self._sink.pos
        try:
            return call(*args)
        except OSError as exc:
            self._fail(exc, mark)
            raise BagWriteError(self.error) from exc

    def _fail(self, exc: OSError, mark: int) -> None:
        self._writer = None  # its state no longer matches the file
        current = self._files[-1]
        try:
            self._sink.cut(mark)
        except OSError:
            self._torn = True  # the reader still reads everything before the torn record
        try:
            self._chunk_indexes, counts = _index_data_section(self.file_path, mark)
        except OSError as read_error:  # not even readable: no summary, no metadata.yaml
            self._torn = self._unread = True
            self.error = _write_error_text(
                exc, self.path, f'the file cannot be read back ({read_error.strerror}), so what '
                f'it holds is not known; `lightstage bag info {self.path}` tells', self.retry)
            return
        current.per_channel = counts
        current.count = sum(counts.values())
        timed = [c for c in self._chunk_indexes if c.message_start_time or c.message_end_time]
        current.start_ns = min((c.message_start_time for c in timed), default=None)
        current.end_ns = max((c.message_end_time for c in timed), default=None)
        self._sync_topic_counts()
        n = self.message_count
        held = (f'the bag holds everything up to {format_time(self.end_ns)}: '
                f'{n} message{"s" if n != 1 else ""}' if n else 'the bag holds no message')
        self.error = _write_error_text(exc, self.path, held, self.retry)

    def _note(self, text: str) -> None:
        self.error = f'{self.error}; {text}' if self.error else text

    def _check_writable(self) -> None:
        if self.closed:
            raise BagError(f'the bag {self.path} is already closed')
        if self._writer is None:
            raise BagWriteError(f'{self.error} (the writer stopped at this error)')

    # -- closing
    def metadata(self) -> dict:
        """The ``rosbag2_bagfile_information`` mapping (version 9) of what the bag holds."""
        start = self.start_ns or 0
        duration = (self.end_ns - self.start_ns) if self.message_count else 0
        return {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': int(duration)},
            'starting_time': {'nanoseconds_since_epoch': int(start)},
            'message_count': int(self.message_count),
            'topics_with_message_count': [
                {'topic_metadata': {'name': t.info.name, 'type': t.info.type,
                                    'serialization_format': t.info.serialization_format,
                                    'offered_qos_profiles': [q.to_dict() for q in t.info.offered_qos],
                                    'type_description_hash': t.info.type_hash},
                 'message_count': int(t.info.count)}
                for t in self._topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [f.path.name for f in self._files],
            'files': [f.to_metadata() for f in self._files],
            'custom_data': dict(self.custom_data) or None,
            'ros_distro': self.ros_distro,
        }

    def _rosbag2_record(self) -> dict[str, str]:
        return {'serialized_metadata': yaml.safe_dump(self.metadata(), sort_keys=False),
                'ROS_DISTRO': self.ros_distro}

    def close(self) -> None:
        """Write the rosbag2 metadata record, the summary and footer, fsync the file, then
        write metadata.yaml (through a fsynced temporary file, renamed) and fsync the
        directory. Never raises for I/O errors: after a write error (before or here) it writes
        what the disk allows for the messages in the files, and `error` says what happened."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            if self._sink is not None:  # None: the next file of a split could not be created
                if self._writer is not None:
                    mark = self._sink.pos
                    try:
                        self._writer.add_metadata('rosbag2', self._rosbag2_record())
                        self._writer.finish()
                        self.summary_written = True
                    except OSError as exc:
                        self._fail(exc, mark)
                if not self.summary_written and not self._torn:
                    self._finish_after_error()
                self._close_fd()
            if not self._unread:
                self._write_metadata_yaml()
            _fsync_dir(self.path)
            if self.created_dir:
                _fsync_dir(self.path.parent)

    def _finish_after_error(self) -> None:
        """Summary and footer for the chunks the file holds, after the mcap writer stopped."""
        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import (DataEnd, Footer, Metadata, MetadataIndex, Statistics,
                                  SummaryOffset)

        start = self._sink.pos
        data = RecordBuilder()
        Metadata(name='rosbag2', metadata=self._rosbag2_record()).write(data)
        metadata_length = data.count
        DataEnd(data_section_crc=0).write(data)
        summary_start = start + data.count
        summary = RecordBuilder()
        offsets = []
        current = self._files[-1]  # this file's own statistics, not the bag's
        counts = {cid: n for cid, n in current.per_channel.items() if n}
        groups = [
            (Opcode.SCHEMA, list(self._schema_records.values())),
            (Opcode.CHANNEL, list(self._channel_records.values())),
            (Opcode.STATISTICS, [Statistics(
                attachment_count=0, channel_count=len(self._channel_records),
                channel_message_counts=counts, chunk_count=len(self._chunk_indexes),
                message_count=current.count, message_end_time=current.end_ns or 0,
                message_start_time=current.start_ns or 0, metadata_count=1,
                schema_count=len(self._schema_records))]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.METADATA_INDEX, [MetadataIndex(offset=start, length=metadata_length,
                                                   name='rosbag2')])]
        for opcode, records in groups:
            group_start = summary.count
            for r in records:
                r.write(summary)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                         group_length=summary.count - group_start))
        offsets_start = summary_start + summary.count
        for o in offsets:
            o.write(summary)
        summary_data = summary.end()
        crc = zlib.crc32(summary_data)
        crc = zlib.crc32(struct.pack('<BQQQ', Opcode.FOOTER, 8 + 8 + 4, summary_start, offsets_start),
                         crc)
        footer = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=offsets_start,
               summary_crc=crc).write(footer)
        try:
            self._sink.write(data.end() + summary_data + footer.end() + MCAP_MAGIC)
            self.summary_written = True
        except OSError as exc:
            try:
                self._sink.cut(start)
            except OSError:
                pass
            self._note(f'the summary and footer could not be written either ({exc.strerror}): the '
                       'file ends after its last complete chunk, which readers take; '
                       f'`lightstage bag recover {self.path}` writes a complete copy')

    def _write_metadata_yaml(self) -> None:
        text = yaml.safe_dump({'rosbag2_bagfile_information': self.metadata()}, sort_keys=False)
        tmp = self.path / (METADATA_FILE + '.tmp')
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
            try:
                _write_all(fd, text.encode())
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.path / METADATA_FILE)
            self.metadata_written = True
        except OSError as exc:
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass
            self._note(f'{METADATA_FILE} could not be written ({exc.strerror}); readers take the '
                       '.mcap file without it')

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close()
        if exc_type is None and self.error:
            raise BagWriteError(self.error)


# --------------------------------------------------------------------------- reader


def _describe_non_mcap(head: bytes, path: Path) -> str:
    if head.startswith(b'SQLite format 3'):
        return (f'{path} is a rosbag2 sqlite3 file; this tool reads MCAP bags only: convert it '
                f'with `ros2 bag convert` (storage_id: mcap) or rosbags-convert')
    if head.startswith(b'\x28\xb5\x2f\xfd'):
        return (f'{path} is zstd-compressed (file compression mode); decompress it first '
                f'(`zstd -d {path.name}`)')
    if not head:
        return f'{path} is empty (0 bytes): the recorder wrote nothing; record again'
    return (f'{path} is not an MCAP file (it starts with {head[:8]!r}, an MCAP file with '
            f'{MCAP_MAGIC!r}); give a bag directory or .mcap file written by `lightstage record` '
            f'or `ros2 bag record -s mcap`')


def _format_ns(ns: int) -> str:
    return f'{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}'


@dataclass
class _Chunk:
    """Messages of one chunk (or one loose message) in file order, with its start time."""
    start_ns: int
    messages: list


class _FileScan:
    """Walk one MCAP file record by record; damaged parts are skipped and described."""

    def __init__(self, path: Path):
        self.path = path
        self.size = path.stat().st_size
        self.schemas: dict = {}
        self.channels: dict = {}
        self.metadata: dict[str, dict] = {}
        self.problems: list[str] = []
        self.complete = False
        self.library = ''
        self.summary = None
        self.chunks = self.chunks_without_crc = 0  # read back by the last walk
        with open(path, 'rb') as f:
            head = f.read(16)
        if head[:len(MCAP_MAGIC)] != MCAP_MAGIC:
            raise BagError(_describe_non_mcap(head, path))
        self._read_summary()

    def _read_summary(self) -> None:
        """Schemas, channels, statistics from the summary, if the file has an intact one."""
        from mcap.reader import SeekingReader
        try:
            with open(self.path, 'rb') as f:
                reader = SeekingReader(f)
                summary = reader.get_summary()
                self.library = reader.get_header().library
                if summary is not None:
                    for m in reader.iter_metadata():
                        self.metadata[m.name] = dict(m.metadata)
        except Exception:  # noqa: BLE001 - any failure means: no usable summary, walk instead
            return
        if summary is None or summary.statistics is None:
            return
        self.summary = summary
        self.schemas.update(summary.schemas)
        self.channels.update(summary.channels)
        self.complete = True

    def walk(self) -> Iterator[_Chunk]:
        """Every intact message, chunk by chunk, in file order. Problems go to .problems."""
        from mcap.opcode import Opcode
        from mcap.records import Channel, Chunk, Metadata, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        problems: list[str] = []
        found_footer = False
        self.chunks = self.chunks_without_crc = 0
        with open(self.path, 'rb') as f:
            f.seek(len(MCAP_MAGIC))
            offset = len(MCAP_MAGIC)
            while True:
                head = f.read(9)
                if len(head) < 9:
                    if not found_footer:
                        problems.append(
                            f'{self.path.name} ends at byte {offset} without the MCAP footer: the '
                            'writer did not close the file (killed, or out of disk)')
                    break
                opcode, length = struct.unpack('<BQ', head)
                if length > self.size - offset - 9:
                    problems.append(
                        f'{self.path.name} is cut off at byte {self.size}: the record at byte '
                        f'{offset} (opcode 0x{opcode:02x}) needs {length} bytes but only '
                        f'{self.size - offset - 9} are left (the writer was killed while writing, '
                        'or the copy is incomplete)')
                    break
                body = f.read(length)
                record_at = offset
                offset += 9 + length
                if opcode == Opcode.FOOTER:
                    found_footer = True
                    break
                if opcode not in (Opcode.CHUNK, Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL,
                                  Opcode.METADATA, Opcode.HEADER):
                    continue  # indexes, statistics, data end: the walk does not need them
                try:
                    reader = StreamReader(io.BytesIO(head + body), skip_magic=True, emit_chunks=True)
                    record = next(iter(reader.records))
                    if isinstance(record, Chunk):
                        self.chunks += 1
                        self.chunks_without_crc += record.uncompressed_crc == 0
                        records = breakup_chunk(record, validate_crc=True)
                    else:
                        records = [record]
                except Exception as exc:  # noqa: BLE001 - damaged data, described and skipped
                    what = 'chunk' if opcode == Opcode.CHUNK else f'record (opcode 0x{opcode:02x})'
                    problems.append(f'{self.path.name}: the {what} at byte {record_at} '
                                    f'({length} bytes) is damaged ({type(exc).__name__}: {exc}); '
                                    'its messages are skipped')
                    continue
                messages = []
                for r in records:
                    if isinstance(r, Schema):
                        self.schemas.setdefault(r.id, r)
                    elif isinstance(r, Channel):
                        self.channels.setdefault(r.id, r)
                    elif isinstance(r, Metadata):
                        self.metadata[r.name] = dict(r.metadata)
                    elif isinstance(r, Message):
                        messages.append(r)
                if not messages:
                    continue
                if isinstance(record, Chunk):
                    yield _Chunk(record.message_start_time, messages)
                else:
                    yield _Chunk(messages[0].log_time, messages)
        if not found_footer:
            self.complete = False
        for p in problems:
            if p not in self.problems:
                self.problems.append(p)


def _resolve_files(path: Path) -> tuple[list[Path], dict | None, list[str]]:
    """The .mcap files of a bag path and its metadata.yaml contents (or None)."""
    problems: list[str] = []
    if not path.exists():
        raise BagError(f'{path} does not exist; give a bag directory (with metadata.yaml and '
                       '.mcap files) or a .mcap file')
    if path.is_file():
        if path.name == METADATA_FILE:
            return _resolve_files(path.parent)
        return [path], None, problems
    meta_path = path / METADATA_FILE
    metadata = None
    if meta_path.is_file():
        try:
            loaded = yaml.safe_load(meta_path.read_text())
            metadata = loaded['rosbag2_bagfile_information']
            if not isinstance(metadata, dict):
                raise TypeError('rosbag2_bagfile_information is not a mapping')
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            problems.append(f'{meta_path} is unreadable ({type(exc).__name__}: {exc}); reading the '
                            '.mcap files of the directory instead')
            metadata = None
    if metadata is not None:
        storage = metadata.get('storage_identifier', 'mcap')
        if storage != 'mcap':
            raise BagError(f'{path} is a rosbag2 bag with storage {storage!r}; this tool reads MCAP '
                           'bags only: convert it with `ros2 bag convert` (storage_id: mcap)')
        if metadata.get('compression_mode'):
            raise BagError(f'{path} uses rosbag2 {metadata.get("compression_mode")} compression '
                           f'({metadata.get("compression_format")}); decompress it first with '
                           '`ros2 bag convert`')
        names = metadata.get('relative_file_paths') or [f.get('path') for f in metadata.get('files', [])]
        files = [path / n for n in names if n]
        missing = [f.name for f in files if not f.is_file()]
        if missing:
            raise BagError(f'{meta_path} lists {", ".join(missing)} but {path} does not hold '
                           f'{"it" if len(missing) == 1 else "them"}; copy the whole bag directory')
        return files, metadata, problems
    files = sorted(path.glob('*.mcap'), key=lambda p: [int(t) if t.isdigit() else t
                                                      for t in re.split(r'(\d+)', p.name)])
    if not files:
        raise BagError(f'{path} holds no metadata.yaml and no .mcap file; give a bag directory '
                       'written by `lightstage record` or `ros2 bag record -s mcap`')
    if not meta_path.exists():
        problems.append(f'{path} has no {METADATA_FILE} (the recorder did not close the bag); '
                        'reading its .mcap files directly')
    return files, None, problems


class BagReader:
    """Read a bag directory or a lone .mcap file; see the module docstring."""

    def __init__(self, path):
        self.path = Path(path)
        self.files, self.metadata_yaml, problems = _resolve_files(self.path)
        self.problems: list[str] = list(problems)
        self._scans = [_FileScan(f) for f in self.files]
        self._info: BagInfo | None = None

    # -- topics
    def _topic_of(self, scan: _FileScan, channel_id: int) -> TopicInfo | None:
        channel = scan.channels.get(channel_id)
        if channel is None:
            return None
        schema = scan.schemas.get(channel.schema_id)
        type_name = schema.name if schema is not None else ''
        if not type_name:  # no schema: the type may still be in metadata.yaml
            for t in (self.metadata_yaml or {}).get('topics_with_message_count', []):
                if t.get('topic_metadata', {}).get('name') == channel.topic:
                    type_name = t['topic_metadata'].get('type', '')
        meta = channel.metadata or {}
        try:
            qos = parse_qos_profiles(meta.get('offered_qos_profiles', ''))
        except (ValueError, yaml.YAMLError) as exc:
            self._problem(f'{channel.topic}: unreadable offered_qos_profiles ({exc}); played with '
                          'default QoS')
            qos = []
        return TopicInfo(channel.topic, type_name, 0, channel.message_encoding, qos,
                         meta.get('topic_type_hash', ''),
                         schema.encoding if schema is not None else '',
                         schema.data.decode(errors='replace') if schema is not None else '')

    def _problem(self, text: str) -> None:
        if text not in self.problems:
            self.problems.append(text)

    # -- info
    def info(self, verify: bool = False) -> BagInfo:
        """Topics, counts, times. Files with an intact summary are summarised from it (fast);
        others -- and all with ``verify`` -- are read through, which also finds damage."""
        if self._info is not None and not verify:
            return self._info
        topics: dict[str, TopicInfo] = {}
        start, end, count = None, None, 0
        complete = True
        distro = ''
        library = ''
        walked = True  # every file read through, not summarised from its summary
        for scan in self._scans:
            library = library or scan.library
            if scan.summary is not None and not verify:
                walked = False
                stats = scan.summary.statistics
                for cid, n in stats.channel_message_counts.items():
                    t = self._merge_topic(topics, scan, cid)
                    if t is not None:
                        t.count += n
                for cid in scan.channels:
                    self._merge_topic(topics, scan, cid)
                if stats.message_count:
                    start = stats.message_start_time if start is None else min(start, stats.message_start_time)
                    end = stats.message_end_time if end is None else max(end, stats.message_end_time)
                count += stats.message_count
            else:
                for chunk in scan.walk():
                    for m in chunk.messages:
                        t = self._merge_topic(topics, scan, m.channel_id)
                        if t is None:
                            self._problem(f'{scan.path.name}: messages of channel {m.channel_id} '
                                          'whose definition was lost are skipped')
                            continue
                        t.count += 1
                        count += 1
                        start = m.log_time if start is None else min(start, m.log_time)
                        end = m.log_time if end is None else max(end, m.log_time)
                for cid in scan.channels:
                    self._merge_topic(topics, scan, cid)
                for p in scan.problems:
                    self._problem(p)
            complete = complete and scan.complete
            distro = distro or scan.metadata.get('rosbag2', {}).get('ROS_DISTRO', '')
        if self.metadata_yaml is None and self.path.is_dir():
            complete = False
        complete = complete and not self.problems
        self._info = BagInfo(
            path=self.path, files=list(self.files),
            size_bytes=sum(f.stat().st_size for f in self.files),
            start_ns=start or 0, end_ns=end or 0, message_count=count, topics=topics,
            complete=complete, problems=list(self.problems),
            ros_distro=distro or (self.metadata_yaml or {}).get('ros_distro', ''),
            library=library, has_metadata_yaml=self.metadata_yaml is not None,
            custom_data={str(k): str(v) for k, v in
                         ((self.metadata_yaml or {}).get('custom_data') or {}).items()},
            verified=walked, chunks=sum(s.chunks for s in self._scans) if walked else 0,
            chunks_without_crc=sum(s.chunks_without_crc for s in self._scans) if walked else 0)
        return self._info

    def _merge_topic(self, topics: dict, scan: _FileScan, channel_id: int) -> TopicInfo | None:
        channel = scan.channels.get(channel_id)
        if channel is None:
            return None
        t = topics.get(channel.topic)
        if t is None:
            t = self._topic_of(scan, channel_id)
            topics[channel.topic] = t
        return t

    # -- messages
    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[BagMessage]:
        """Every intact message (of ``topics``, with start_ns <= log time < end_ns), in log
        time order. Damage found on the way is added to ``self.problems``."""
        wanted = set(topics) if topics is not None else None
        for scan in self._scans:
            type_cache: dict[int, TopicInfo | None] = {}
            heap: list = []
            tie = itertools.count()
            for chunk in scan.walk():
                while heap and heap[0][0] < chunk.start_ns:
                    yield heapq.heappop(heap)[2]
                for m in chunk.messages:
                    if m.channel_id not in type_cache:
                        type_cache[m.channel_id] = self._topic_of(scan, m.channel_id)
                    t = type_cache[m.channel_id]
                    if t is None:
                        self._problem(f'{scan.path.name}: messages of channel {m.channel_id} '
                                      'whose definition was lost are skipped')
                        continue
                    if wanted is not None and t.name not in wanted:
                        continue
                    if start_ns is not None and m.log_time < start_ns:
                        continue
                    if end_ns is not None and m.log_time >= end_ns:
                        continue
                    heapq.heappush(heap, (m.log_time, next(tie), BagMessage(
                        t.name, t.type, bytes(m.data), m.log_time, m.publish_time, m.sequence)))
            while heap:
                yield heapq.heappop(heap)[2]
            for p in scan.problems:
                self._problem(p)


# --------------------------------------------------------------------------- tools


@dataclass
class Recovery:
    """What `recover_bag` did.

    ``source``: the source bag's info before copying; ``source_problems``: everything found
    damaged or missing in it (filled while reading); ``listed``: how many messages its
    summary or metadata.yaml lists (None: it has neither, so what was lost after a cut is not
    known); ``read``: intact messages read from it; ``info``: the new bag as read back (None:
    nothing was recovered and ``dst`` was not written); ``error``: why the copy stopped
    before the end ('' = every intact message was copied).
    """
    src: Path
    dst: Path
    source: BagInfo
    listed: int | None
    source_problems: list = field(default_factory=list)
    read: int = 0
    info: BagInfo | None = None
    error: str = ''

    @property
    def recovered(self) -> int:
        return self.info.message_count if self.info is not None else 0

    @property
    def unreadable(self) -> int | None:
        """Messages the source lists but that were damaged or cut off (None: not known)."""
        if self.listed is None or self.error:
            return None
        return max(0, self.listed - self.read)


def _listed_count(reader: 'BagReader', source: BagInfo) -> int | None:
    counts = []
    if reader._scans and all(scan.summary is not None for scan in reader._scans):
        counts.append(source.message_count)
    n = (reader.metadata_yaml or {}).get('message_count')
    if isinstance(n, int) and not isinstance(n, bool):
        counts.append(n)
    return max(counts) if counts else None


def recover_bag(src, dst, *, compression: str = 'lz4') -> Recovery:
    """Copy every intact message of bag ``src`` into a new bag ``dst`` and say what was lost.

    Topics keep their types, schemas, QoS and type hashes. ``dst`` must not exist (or be an
    empty directory); it is written only if there is something to recover. When writing stops
    midway (disk full), ``dst`` holds the messages copied until then, and its summary and
    metadata.yaml list exactly those (`BagWriter`); ``error`` says what happened.
    """
    src, dst = Path(src), Path(dst)
    reader = BagReader(src)
    source = reader.info()
    check_output_dir(dst)
    result = Recovery(src, dst, source, _listed_count(reader, source))
    writer: BagWriter | None = None
    try:
        try:
            for m in reader.messages():
                if writer is None:
                    writer = BagWriter(dst, compression=compression,
                                       library='lightstage_bringup bag recover',
                                       custom_data={'recovered_from': str(src)},
                                       retry=f'run `lightstage bag recover {src} -o {dst}` '
                                             f'again once {dst} is deleted')
                    for t in source.topics.values():
                        writer.add_topic(t.name, t.type, t.offered_qos, type_hash=t.type_hash,
                                         schema=(t.schema_encoding, t.schema_text),
                                         serialization_format=t.serialization_format)
                writer.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns, m.sequence)
                result.read += 1
        except BagWriteError as exc:
            result.error = str(exc)
        except OSError as exc:
            result.error = (f'reading {src} failed after {result.read} messages '
                            f'({exc.strerror or exc}); check the disk it is on and run '
                            f'`lightstage bag recover {src} -o {dst}` again once {dst} is deleted')
    finally:
        result.source_problems = list(reader.problems)
        if writer is not None:
            if result.source_problems:
                writer.custom_data['source_problems'] = '; '.join(result.source_problems)
            if result.error:
                writer.custom_data['recovery_stopped'] = result.error
            writer.close()
            if writer.error and not result.error:
                result.error = writer.error
    if writer is not None:
        if writer.message_count:
            result.info = BagReader(dst).info()
        else:
            writer._discard()  # nothing in it: no bag is better than an empty one
    return result


def recover(src, dst, *, compression: str = 'lz4') -> BagInfo:
    """`recover_bag` for callers that want the new bag or an exception: the info of ``dst``;
    `BagWriteError` if the copy stopped midway, `BagError` if nothing could be recovered."""
    result = recover_bag(src, dst, compression=compression)
    if result.error:
        raise BagWriteError(result.error)
    if result.info is None:
        raise BagError(f'nothing could be recovered: {src} holds no intact message '
                       f'({"; ".join(result.source_problems) or "it is empty"}); no bag was written')
    return result.info


def format_size(n: int) -> str:
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if n < 1024 or unit == 'GiB':
            return f'{n:.1f} {unit}' if unit != 'B' else f'{n} B'
        n /= 1024
    return f'{n:.1f} GiB'


def format_time(ns: int) -> str:
    """A log time as local date and time, with the ns since the epoch."""
    t = _dt.datetime.fromtimestamp(ns / 1e9)
    return f'{t.strftime("%b %d %Y %H:%M:%S")}.{(ns // 1_000_000) % 1000:03d} ({_format_ns(ns)})'


def format_info(info: BagInfo, verbose: bool = False) -> str:
    """A summary in the layout of ``ros2 bag info`` (topics, then services)."""
    ordered = sorted(info.topics.values(), key=lambda t: t.name)
    topics = [t for t in ordered if not t.is_service_event]
    services = [t for t in ordered if t.is_service_event]
    lines = [f'Files:             {", ".join(f.name for f in info.files)}',
             f'Bag size:          {format_size(info.size_bytes)}',
             f'Storage id:        {info.storage_identifier}',
             f'ROS Distro:        {info.ros_distro or "unknown"}',
             f'Duration:          {info.duration_ns / 1e9:.9f}s']
    if info.message_count:
        lines += [f'Start:             {format_time(info.start_ns)}',
                  f'End:               {format_time(info.end_ns)}']
    n_events = sum(s.count for s in services)
    lines.append(f'Messages:          {info.message_count}' + (
        f' ({info.message_count - n_events} on topics, {n_events} service events)' if n_events else ''))
    if info.verified:
        lines.append(f'Checked:           every message read back from its chunk ({info.chunks} '
                     'chunks, CRCs verified' + (
                         f'; {info.chunks_without_crc} carry no CRC, as rosbag2 writes by default: '
                         'those were only decompressed and parsed' if info.chunks_without_crc
                         else '') + ')')
    else:
        lines.append('Checked:           NO: summarised from the files\' summaries, chunk CRCs '
                     f'not checked; `lightstage bag info {info.path}` (without --no-verify) checks '
                     'them')
    width = max([len(t.name) for t in topics] + [1])
    for i, t in enumerate(topics):
        head = 'Topic information: ' if i == 0 else ' ' * 19
        lines.append(f'{head}Topic: {t.name:<{width}} | Type: {t.type} | Count: {t.count} | '
                     f'Serialization Format: {t.serialization_format}')
        if verbose:
            groups: dict[str, int] = {}
            for q in t.offered_qos:
                depth = f'keep_last {q.depth}' if q.history == 'keep_last' else q.history
                key = f'{q.reliability}, {q.durability}, history {depth}'
                groups[key] = groups.get(key, 0) + 1
            for key, n in groups.items():
                lines.append(' ' * 27 + f'offered QoS ({n} publisher{"s" if n > 1 else ""}): {key}')
    lines.append(f'Services:          {len(services)}')
    swidth = max([len(s.service_name) for s in services] + [1])
    for i, s in enumerate(services):
        head = 'Service information: ' if i == 0 else ' ' * 21
        lines.append(f'{head}Service: {s.service_name:<{swidth}} | Type: {s.service_type} | '
                     f'Event Count: {s.count} | Serialization Format: {s.serialization_format}')
    deleted = info.custom_data.get('deleted_files')
    if deleted:
        lines.append('')
        lines.append(f'NOT KEPT: {deleted}; the bag holds the newest files only')
    stopped = info.custom_data.get('recovery_stopped')
    if stopped:
        lines.append('')
        lines.append(f'PARTIAL COPY of {info.custom_data.get("recovered_from", "another bag")}: '
                     f'the recovery stopped ({stopped}); this bag holds only what was copied '
                     'before that')
    if not info.complete:
        lines.append('')
        lines.append('INCOMPLETE BAG: ' + ('; '.join(info.problems) or 'no summary'))
        lines.append(f'All {info.message_count} intact messages above are readable and playable; '
                     f'`lightstage bag recover {info.path}` writes a complete copy.')
    return '\n'.join(lines)
