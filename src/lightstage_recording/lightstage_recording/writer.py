"""Write a bag as ``ros2 bag record -s mcap`` (Jazzy) does, through the `mcap` library's
`Writer` (the records, chunks, indexes, summary and footer are all its own):

- the MCAP header has profile ``ros2``;
- one schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, the ``.msg``
  text with its dependencies (`msg_definitions.full_definition`);
- one channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (the
  publishers' QoS as rosbag2 version-9 YAML) and ``topic_type_hash`` (``RIHS01_...``);
- every message: the serialized CDR bytes as received, ``log_time`` = receive time,
  ``publish_time`` = send time (ns since the epoch);
- a metadata record ``rosbag2`` (``serialized_metadata``, ``ROS_DISTRO``) and the
  ``metadata.yaml`` (`layout`) written when the bag is closed.

`BagWriter.flush` hands the chunk in progress to the OS (no fsync); `close` fsyncs the file,
metadata.yaml and the directory. A write error (disk full) stops the writer: the file is cut
back to the end of its last complete chunk and left there -- it reads like the file of a
recorder killed between two flushes, and `lightstage bag recover` (`recover.recover_bag`)
writes a complete copy -- and metadata.yaml lists exactly what the files hold, as far as the
disk allows (`BagWriteError`, `BagWriter.error`).
"""
from __future__ import annotations

import itertools
import os
import threading
from dataclasses import dataclass, field, replace
from importlib.metadata import version
from pathlib import Path

import yaml
from mcap.records import Channel, Schema
from mcap.writer import CompressionType, Writer

from . import fileio, msg_definitions
from .exceptions import BagError, BagWriteError
from .formatting import format_size, format_time
from .layout import METADATA_FILE, METADATA_VERSION, ROS_DISTRO, check_output_dir, file_name
from .qos import dump_qos_profiles, parse_qos_profiles
from .summary import TopicInfo

COMPRESSIONS = ('lz4', 'none')
MIN_SPLIT_SIZE_BYTES = 1024  # rosbag2's MCAP storage refuses smaller max_bag_size too


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

    def copy(self) -> '_FileStats':
        return replace(self, per_channel=dict(self.per_channel))

    def to_metadata(self) -> dict:
        """Its entry of metadata.yaml's ``files``."""
        return {'path': self.path.name,
                'starting_time': {'nanoseconds_since_epoch': int(self.start_ns or 0)},
                'duration': {'nanoseconds': int((self.end_ns - self.start_ns) if self.count else 0)},
                'message_count': int(self.count)}


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
    The counts (`message_count`, `topics`) then are those of the messages in the files. The
    file is left as it is, without summary and footer: readers walk it as the file of a killed
    recorder, and finishing it is the recovery's job (`recover.recover_bag`, `lightstage bag
    recover`), not the writer's. `close` still writes ``metadata.yaml`` for those messages, as
    far as the disk allows. `error` keeps the message ('' while all is well); `close` does not
    raise, the context manager does (`BagWriteError`) if an error was not raised before.
    ``retry``: what to do again once the disk is fixed, for the messages.
    """

    def __init__(self, path, *, compression: str = 'lz4', chunk_size_bytes: int = 1 << 20,
                 library: str = 'lightstage_recording', ros_distro: str = ROS_DISTRO,
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
        self._library = f'{library}; mcap-python {version("mcap")}'
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._schema_records: dict = {}   # id -> mcap Schema, registered in each new file
        self._channel_records: dict = {}  # id -> mcap Channel, too
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
            self.discard()
            raise BagWriteError(fileio.write_error_text(exc, self.path, 'nothing was written',
                                                        self.retry)) from None

    # -- files
    def _open_file(self) -> None:
        """Start the next file (``NAME_<i>.mcap``) with every schema and channel known so far."""
        self.file_path = file_name(self.path, len(self._files) + len(self.deleted_files))
        self._files.append(_FileStats(self.file_path))
        self._in_file = _FileStats(self.file_path)  # what of it has reached the file
        self._sink = fileio.Sink(self.file_path)
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
        max_bag_files. A write error stops the writer (`_fail`), as anywhere."""
        done = self._files[-1]
        self._finish_file()
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
            self.error = fileio.write_error_text(exc, failed.path, held, self.retry)
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

    def discard(self) -> None:
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
            # counted first: the chunk it completes holds it (a write error takes the counts
            # back to what reached the file, `_fail`)
            t.info.count += 1
            self._files[-1].add(t.channel_id, log_time_ns)
            self._io(self._writer.add_message, t.channel_id, log_time_ns, data,
                     int(publish_time_ns if publish_time_ns is not None else log_time_ns), seq)
            self._unchunked += len(data) + 31  # + the message record's header
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
        """One call of the mcap writer. Each call leaves whole records in the file, and one that
        writes leaves no message behind in the chunk builder (it wrote the chunk they completed):
        what was added so far is then in the file. On an OSError the file is cut back to where
        the call started and the writer stops."""
        mark = self._sink.pos
        try:
            result = call(*args)
        except OSError as exc:
            self._fail(exc, mark)
            raise BagWriteError(self.error) from exc
        if self._sink.pos != mark:
            self._in_file = self._files[-1].copy()
        return result

    def _fail(self, exc: OSError, mark: int) -> None:
        """Stop at a write error: the file is cut back to ``mark``, the end of its last
        complete chunk, and left without summary and footer -- what a killed recorder leaves,
        which every reader takes and `recover.recover_bag` completes; the counts become those
        of the messages in the files."""
        self._writer = None  # its state no longer matches the file
        try:
            self._sink.cut(mark)
            ends = 'ends after its last complete chunk'
        except OSError:  # readers skip the torn record at the end
            ends = 'ends in a torn record after its last complete chunk (it could not be cut back)'
        self._files[-1] = self._in_file
        self._sync_topic_counts()
        n = self.message_count
        held = (f'the bag holds everything up to {format_time(self.end_ns)}: '
                f'{n} message{"s" if n != 1 else ""}; {self.file_path.name} {ends}, without a '
                f'summary: `lightstage bag recover {self.path}` writes a complete copy'
                if n else 'the bag holds no message')
        self.error = fileio.write_error_text(exc, self.path, held, self.retry)

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

    def _finish_file(self) -> None:
        """End the file in progress as mcap's `Writer` does: the chunk in progress, the rosbag2
        metadata record, summary and footer (`BagWriteError` as for any write)."""
        self._io(self._writer.flush)
        self._io(self._finish_mcap)
        self.summary_written = True

    def _finish_mcap(self) -> None:
        self._writer.add_metadata('rosbag2', self._rosbag2_record())
        self._writer.finish()

    def close(self) -> None:
        """Finish the file in progress (`_finish_file`), fsync it, then write metadata.yaml
        (through a fsynced temporary file, renamed) and fsync the directory. Never raises for
        I/O errors: after a write error (before or here) the file ends after its last complete
        chunk, metadata.yaml lists the messages in the files as far as the disk allows, and
        `error` says what happened."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            if self._sink is not None:  # None: the next file of a split could not be created
                if self._writer is not None:
                    try:
                        self._finish_file()
                    except BagWriteError:
                        pass  # `error` says what happened
                self._close_fd()
            self._write_metadata_yaml()
            fileio.fsync_dir(self.path)
            if self.created_dir:
                fileio.fsync_dir(self.path.parent)

    def _write_metadata_yaml(self) -> None:
        text = yaml.safe_dump({'rosbag2_bagfile_information': self.metadata()}, sort_keys=False)
        try:
            fileio.replace_atomically(self.path / METADATA_FILE, text.encode())
            self.metadata_written = True
        except OSError as exc:
            self._note(f'{METADATA_FILE} could not be written ({exc.strerror}); readers take the '
                       '.mcap file without it')

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close()
        if exc_type is None and self.error:
            raise BagWriteError(self.error)
