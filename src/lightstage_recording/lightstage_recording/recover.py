"""`lightstage bag recover`: a complete copy of the intact part of an incomplete or damaged
bag (a recorder that was killed, or whose disk filled up; a file cut off or damaged), and
what was lost."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .exceptions import BagWriteError
from .layout import check_output_dir
from .reader import BagReader
from .summary import BagInfo
from .writer import BagWriter


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


def recover_bag(src, dst, *, compression: str = 'lz4') -> Recovery:
    """Copy every intact message of bag ``src`` into a new bag ``dst`` and say what was lost.

    Topics keep their types, schemas, QoS and type hashes. ``dst`` must not exist (or be an
    empty directory); it is written only if there is something to recover. When writing stops
    midway (disk full), ``dst`` holds the messages copied until then, and its summary and
    metadata.yaml list exactly those (`BagWriter`); ``error`` says what happened.
    """
    return copy_bag(src, dst, compression=compression, verb='recover')


def copy_bag(src, dst, *, compression: str = 'lz4', verb: str = 'recover',
             source_key: str = 'recovered_from', topic_as=None,
             custom_data: dict | None = None) -> Recovery:
    """`recover_bag`, and `lightstage bag export`'s copy: ``topic_as(TopicInfo)`` gives each
    topic's (type, (schema encoding, schema text), type hash) in ``dst`` (default: as in
    ``src``); ``verb`` names the command in the bag's library and in what to do again;
    ``custom_data`` goes into ``dst``'s metadata.yaml, with ``src`` under ``source_key``."""
    src, dst = Path(src), Path(dst)
    reader = BagReader(src)
    source = reader.info()
    check_output_dir(dst)
    result = Recovery(src, dst, source, reader.listed_count())
    if topic_as is None:
        def topic_as(t):
            return t.type, (t.schema_encoding, t.schema_text), t.type_hash
    writer: BagWriter | None = None
    try:
        try:
            for m in reader.messages():
                if writer is None:
                    writer = BagWriter(dst, compression=compression,
                                       library=f'lightstage_recording bag {verb}',
                                       custom_data={source_key: str(src), **(custom_data or {})},
                                       retry=f'run `lightstage bag {verb} {src} -o {dst}` '
                                             f'again once {dst} is deleted')
                    for t in source.topics.values():
                        type_name, schema, type_hash = topic_as(t)
                        writer.add_topic(t.name, type_name, t.offered_qos, type_hash=type_hash,
                                         schema=schema,
                                         serialization_format=t.serialization_format)
                writer.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns, m.sequence)
                result.read += 1
        except BagWriteError as exc:
            result.error = str(exc)
        except OSError as exc:
            result.error = (f'reading {src} failed after {result.read} messages '
                            f'({exc.strerror or exc}); check the disk it is on and run '
                            f'`lightstage bag {verb} {src} -o {dst}` again once {dst} is deleted')
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
            writer.discard()  # nothing in it: no bag is better than an empty one
    return result
