"""Read a bag: a bag directory (or one .mcap file) as topics, a summary and its messages in
log-time order.

Files with an intact summary are summarised from it; the messages are read by walking each
file record by record (`scan.FileScan`), so a bag whose writer was killed (no summary, no
footer, no metadata.yaml) or whose file is damaged still yields every intact message; what was
wrong is in ``BagInfo.problems`` / ``BagReader.problems``. Files that cannot be read at all
raise `BagError`, whose message says what was wrong and what to do -- among them files that
would make the reader hold more than ``max_chunk_bytes`` in memory (`scan.MAX_CHUNK_BYTES`) and
a metadata.yaml naming anything but the regular files of the bag directory, each once
(`layout.resolve_files`).
"""
from __future__ import annotations

import heapq
import itertools
from pathlib import Path
from typing import Iterable, Iterator

import yaml

from .layout import resolve_files
from .losses import LossCounter
from .qos import parse_qos_profiles
from .scan import MAX_CHUNK_BYTES, FileScan
from .summary import BagInfo, BagMessage, TopicInfo


class BagReader:
    """Read a bag directory or a lone .mcap file; see the module docstring."""

    def __init__(self, path, max_chunk_bytes: int = MAX_CHUNK_BYTES):
        self.path = Path(path)
        self.files, self.metadata_yaml, problems = resolve_files(self.path)
        self.problems: list[str] = list(problems)
        self._scans = [FileScan(f, max_chunk_bytes) for f in self.files]
        self._info: BagInfo | None = None

    # -- topics
    def _topic_of(self, scan: FileScan, channel_id: int) -> TopicInfo | None:
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

    def listed_count(self) -> int | None:
        """How many messages the bag's own records say it held: its files' summaries (if every
        file has one) or metadata.yaml, the larger; None when neither tells."""
        counts = []
        if self._scans and all(scan.summary is not None for scan in self._scans):
            counts.append(self.info().message_count)
        n = (self.metadata_yaml or {}).get('message_count')
        if isinstance(n, int) and not isinstance(n, bool):
            counts.append(n)
        return max(counts) if counts else None

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
        losses = LossCounter()
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
                        losses.add_topic(t.name, t.type, len(t.offered_qos))
                        losses.message(t.name, m.sequence, m.data)
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
            chunks_without_crc=sum(s.chunks_without_crc for s in self._scans) if walked else 0,
            losses=losses if walked else None)
        return self._info

    def _merge_topic(self, topics: dict, scan: FileScan, channel_id: int) -> TopicInfo | None:
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
