"""Bags described for people: sizes, log times, and the summary `lightstage bag info` prints
in the layout of ``ros2 bag info``."""
from __future__ import annotations

import datetime as _dt

from lightstage_graph.stamps import format_stamp

from .summary import BagInfo


def format_size(n: int) -> str:
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if n < 1024 or unit == 'GiB':
            return f'{n:.1f} {unit}' if unit != 'B' else f'{n} B'
        n /= 1024
    return f'{n:.1f} GiB'


def format_time(ns: int) -> str:
    """A log time as local date and time, with the ns since the epoch."""
    t = _dt.datetime.fromtimestamp(ns / 1e9)
    return f'{t.strftime("%b %d %Y %H:%M:%S")}.{(ns // 1_000_000) % 1000:03d} ({format_stamp(ns)})'


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
    if info.losses is None:
        lines.append('Lost:              not counted (--no-verify reads no message; without it the '
                     'publishers\' sequence gaps and unmatched service events are counted)')
    elif info.losses.lost_any:
        lines.append('')
        lines.append('LOST WHILE RECORDING (sent by the graph, never in the bag):')
        lines.extend(f'  {text}' for text in info.losses.lines())
    deleted = info.custom_data.get('deleted_files')
    if deleted:
        lines.append('')
        lines.append(f'NOT KEPT: {deleted}; the bag holds the newest files only')
    stopped = info.custom_data.get('recovery_stopped')
    if stopped:
        lines.append('')
        source = (info.custom_data.get('recovered_from') or info.custom_data.get('exported_from')
                  or 'another bag')
        lines.append(f'PARTIAL COPY of {source}: '
                     f'the recovery stopped ({stopped}); this bag holds only what was copied '
                     'before that')
    if not info.complete:
        lines.append('')
        lines.append('INCOMPLETE BAG: ' + ('; '.join(info.problems) or 'no summary'))
        lines.append(f'All {info.message_count} intact messages above are readable and playable; '
                     f'`lightstage bag recover {info.path}` writes a complete copy.')
    return '\n'.join(lines)
