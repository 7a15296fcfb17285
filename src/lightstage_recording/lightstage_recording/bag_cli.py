"""`lightstage record`, `lightstage play` and `lightstage bag info|recover|export`.

``record`` and ``play`` run the recorder / player node in this process with the project's
ROS environment (LOCALHOST discovery, `ros_env`); ``bag`` reads bags without ROS.

Exit codes: 0 done; 1 a failure while running (record: a write error, e.g. disk full, stopped
the recording -- the bag is closed with what it holds; play: no subscriber matched in time;
bag info: the bag is incomplete or damaged -- its intact part is still summarised; bag
recover / export: nothing could be copied, or the copy stopped midway); 2 bad arguments or a bag
that cannot be read at all.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lightstage_graph.output import print_out
from lightstage_graph.ros_env import apply_ros_environment

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def _usage_error(args, prog: str, checks: list[tuple[bool, str]]) -> int | None:
    """EXIT_USAGE, with the message printed, for the first failed (ok, message) check or a bad
    --domain-id; else None, with the project's ROS environment applied (before rclpy loads)."""
    problems = [message for ok, message in checks if not ok]
    if not problems:
        try:
            apply_ros_environment(args.domain_id)  # before rclpy loads
        except ValueError as exc:
            problems.append(str(exc))
    if problems:
        print(f'{prog}: {problems[0]}', file=sys.stderr)
        return EXIT_USAGE
    return None


def _params(values: dict):
    from rclpy.parameter import Parameter
    return [Parameter(name, value=value) for name, value in values.items() if value is not None]


# ----------------------------------------------------------------------------- record
def record_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='lightstage record',
        description='Record topics of the running graph (by default all of them, with the calls '
                    'of services that have introspection on) into a bag in rosbag2\'s MCAP '
                    'layout, which `lightstage bag`, `lightstage play` and rosbags\' Reader '
                    'read. rosbags\' AnyReader and rosbags-convert, and mcap_ros2, '
                    'cannot take the type names of service events (nor in rosbag2\'s own bags): '
                    '`lightstage bag export BAG` writes a copy they read. Stops on Ctrl-C / '
                    'SIGTERM or after --max-duration-s and '
                    'prints what it recorded, and what it lost (messages the publishers sent '
                    'that never arrived, service calls with one event missing).')
    p.add_argument('topics', nargs='*', metavar='TOPIC',
                   help='record only these topics (default: every topic)')
    p.add_argument('-o', '--output', default='', metavar='DIR',
                   help='bag directory to create (default: rosbag2_YYYY_MM_DD-HH_MM_SS)')
    p.add_argument('-e', '--regex', default='', metavar='RE',
                   help='also record topics whose name matches RE (alone: only those)')
    p.add_argument('-x', '--exclude', default='', metavar='RE',
                   help='leave out topics whose name matches RE')
    p.add_argument('--no-services', action='store_true',
                   help='leave out service events (<service>/_service_event)')
    p.add_argument('--include-hidden-topics', action='store_true',
                   help='also record hidden topics (e.g. action feedback)')
    p.add_argument('--max-duration-s', type=float, default=0.0, metavar='S',
                   help='stop after S seconds (default: until Ctrl-C)')
    p.add_argument('-b', '--max-bag-size-bytes', type=int, default=0, metavar='N',
                   help='split: start the next file of the bag before one reaches N bytes (as '
                        '`ros2 bag record --max-bag-size`; default 0: no limit, else >= 1024)')
    p.add_argument('-d', '--max-bag-duration-s', type=float, default=0.0, metavar='S',
                   help='split: start the next file once one spans S seconds (as `ros2 bag '
                        'record --max-bag-duration`; default 0: no limit)')
    p.add_argument('--max-bag-files', type=int, default=0, metavar='N',
                   help='keep only the newest N files of a split bag, deleting the oldest '
                        '(default 0: keep all)')
    p.add_argument('--compression', choices=('lz4', 'none'), default='lz4')
    p.add_argument('--chunk-size-bytes', type=int, default=1 << 20, metavar='N')
    p.add_argument('--qos-depth', type=int, default=100, metavar='N',
                   help='keep-last depth of the subscriptions (default 100)')
    p.add_argument('--discovery-period-s', type=float, default=0.5, metavar='S',
                   help='how often to look for new topics (default 0.5)')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or 0)')
    return p


def record_main(argv: list[str] | None = None) -> int:
    args = record_parser().parse_args(sys.argv[1:] if argv is None else argv)
    prog = 'lightstage record'
    checks = [(args.max_duration_s >= 0, '--max-duration-s must be >= 0'),
              (args.chunk_size_bytes >= 1024, '--chunk-size-bytes must be >= 1024'),
              (args.max_bag_size_bytes == 0 or args.max_bag_size_bytes >= 1024,
               '--max-bag-size-bytes must be 0 (no limit) or >= 1024'),
              (0 <= args.max_bag_duration_s <= 1e9, '--max-bag-duration-s must be in 0..1e9 (0: no limit)'),
              (args.max_bag_files >= 0, '--max-bag-files must be >= 0 (0: keep all)'),
              (args.qos_depth >= 1, '--qos-depth must be >= 1'),
              (0.05 <= args.discovery_period_s <= 60, '--discovery-period-s must be in 0.05..60')]
    rc = _usage_error(args, prog, checks)
    if rc is not None:
        return rc
    from rclpy.exceptions import InvalidParameterValueException

    from . import recorder_node
    values = {'output_dir': args.output, 'include_regex': args.regex,
              'exclude_regex': args.exclude, 'record_services': not args.no_services,
              'include_hidden_topics': args.include_hidden_topics,
              'max_duration_s': float(args.max_duration_s), 'compression': args.compression,
              'chunk_size_bytes': args.chunk_size_bytes, 'qos_depth': args.qos_depth,
              'discovery_period_s': float(args.discovery_period_s),
              'max_bag_size_bytes': args.max_bag_size_bytes,
              'max_bag_duration_s': float(args.max_bag_duration_s),
              'max_bag_files': args.max_bag_files,
              'topics': list(args.topics) or None}
    try:
        return recorder_node.run(args=['lightstage-record'], parameter_overrides=_params(values))
    except InvalidParameterValueException as exc:
        print(f'{prog}: {exc}', file=sys.stderr)
        return EXIT_USAGE


# ----------------------------------------------------------------------------- play
def play_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='lightstage play',
        description='Publish the messages of a bag into the graph as recorded: the recorded '
                    'bytes, QoS and timing. Service events, /rosout and /parameter_events are '
                    'left out unless --topics names them.')
    p.add_argument('bag', metavar='BAG', help='bag directory or .mcap file')
    p.add_argument('--topics', nargs='+', default=None, metavar='TOPIC',
                   help='play only these topics')
    p.add_argument('--exclude', default=None, metavar='RE',
                   help='leave out topics matching RE (default: service events, /rosout, '
                        '/parameter_events)')
    p.add_argument('-r', '--rate', type=float, default=1.0, help='speed factor (default 1.0)')
    p.add_argument('--start-offset-s', type=float, default=0.0, metavar='S',
                   help='skip the first S seconds of the bag')
    p.add_argument('-l', '--loop', action='store_true', help='play again and again until Ctrl-C')
    p.add_argument('--wait-for', nargs='+', default=None, metavar='TOPIC',
                   help='start once each of these topics has a matched subscriber')
    p.add_argument('--wait-timeout-s', type=float, default=10.0, metavar='S',
                   help='give up waiting for --wait-for subscribers after S seconds (default 10)')
    p.add_argument('--delay-s', type=float, default=0.0, metavar='S',
                   help='wait S seconds before the first message (after --wait-for); lets a '
                        'subscriber that was just matched finish matching the player, so its '
                        'first messages are not lost')
    p.add_argument('--remap', action='append', default=[], metavar='FROM:=TO',
                   help='publish the bag\'s topic FROM on TO (a ROS remapping rule; repeatable), '
                        'e.g. /image_raw:=/camera/image_raw for a bag recorded before the camera '
                        'topics moved; --topics and --wait-for name the bag\'s topics')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or 0)')
    return p


def play_main(argv: list[str] | None = None) -> int:
    args = play_parser().parse_args(sys.argv[1:] if argv is None else argv)
    prog = 'lightstage play'
    checks = [(0.01 <= args.rate <= 100, '--rate must be in 0.01..100'),
              (args.start_offset_s >= 0, '--start-offset-s must be >= 0'),
              (args.wait_timeout_s >= 0, '--wait-timeout-s must be >= 0'),
              *((':=' in r and all(r.split(':=', 1)), f'--remap {r!r}: write FROM:=TO, e.g. '
                 '/image_raw:=/camera/image_raw') for r in args.remap)]
    rc = _usage_error(args, prog, checks)
    if rc is not None:
        return rc
    from . import player_node
    if args.remap:
        rc = _check_remaps(prog, args)
        if rc is not None:
            return rc
    values = {'bag': str(Path(args.bag)), 'topics': args.topics, 'exclude_regex': args.exclude,
              'rate': float(args.rate), 'start_offset_s': float(args.start_offset_s),
              'loop': bool(args.loop), 'wait_for_subscribers': args.wait_for,
              'wait_timeout_s': float(args.wait_timeout_s), 'delay_s': float(args.delay_s)}
    remap = [a for rule in args.remap for a in ('-r', rule)]
    return player_node.run(args=['lightstage-play', *(['--ros-args', *remap] if remap else [])],
                           parameter_overrides=_params(values))


def _check_remaps(prog: str, args) -> int | None:
    """EXIT_USAGE with a message for --remap rules the bag cannot be played with (before a
    node exists: rcl would answer with a traceback), else None."""
    from .exceptions import BagError
    from .player_node import PlayerError, check_remaps
    from .reader import BagReader
    from .recording import DEFAULT_PLAY_EXCLUDE, select_play_topics
    try:
        info = BagReader(args.bag).info()
        types = {name: t.type for name, t in info.topics.items()}
        played = select_play_topics(info.topics, args.topics,
                                    args.exclude if args.exclude is not None
                                    else DEFAULT_PLAY_EXCLUDE)
        check_remaps(args.remap, types, played)
    except (BagError, PlayerError, ValueError) as exc:
        print(f'{prog}: {exc}', file=sys.stderr)
        return EXIT_USAGE
    return None


# ----------------------------------------------------------------------------- bag
def bag_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='lightstage bag', description='Inspect and repair bags.')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND')
    info = sub.add_parser('info', help='summarise a bag (like `ros2 bag info`)',
                          description='Summarise a bag: files, size, duration, topics with types '
                                      'and counts, recorded services. Every chunk is read back '
                                      'and its CRC checked (--no-verify: trust the summaries). '
                                      'Exit 1 when the bag is incomplete or damaged (its intact '
                                      'part is summarised).')
    info.add_argument('bag', metavar='BAG')
    info.add_argument('--json', action='store_true', help='print JSON')
    info.add_argument('-v', '--verbose', action='store_true', help='also the recorded QoS')
    info.add_argument('--no-verify', dest='verify', action='store_false',
                      help='trust the files\' summaries instead of reading every chunk back and '
                           'checking its CRC (faster on very large bags; the output then says '
                           'the CRCs were not checked)')
    info.add_argument('--verify', action='store_true', default=True,
                      help='read every chunk back and check its CRC (the default)')
    recover = sub.add_parser(
        'recover', help='copy the intact part of an incomplete or damaged bag into a complete bag',
        description='Copy every intact message of BAG into a new, complete bag (summary, footer, '
                    'metadata.yaml) and print what was damaged or lost in BAG. Exit 0 when every '
                    'intact message was copied; 1 when nothing could be recovered (no bag is '
                    'written) or the copy stopped midway (the new bag and its metadata.yaml hold '
                    'what was copied until then); 2 when BAG cannot be read at all or DIR exists.')
    recover.add_argument('bag', metavar='BAG')
    recover.add_argument('-o', '--output', default=None, metavar='DIR',
                         help='new bag directory (default: BAG_recovered); it must not exist, or '
                              'be an empty directory')
    export = sub.add_parser(
        'export', help='copy a bag for rosbags (AnyReader, rosbags-convert) and mcap_ros2',
        description='Copy BAG into a new bag that rosbags (Reader, AnyReader, rosbags-convert) '
                    'and mcap_ros2 (iter_decoded_messages) open and decode, service events '
                    'included: service and action types (pkg/srv/Classify_Event, ...) are '
                    'renamed to message types (pkg/msg/ClassifyEvent, ...) without a type hash; '
                    'every message, time, QoS and the other types are copied as they are. Those '
                    'readers cannot take the type names rosbag2 gives service events (nor can '
                    'they read rosbag2\'s own bags with service events); play the original. '
                    'Exit codes as bag recover.')
    export.add_argument('bag', metavar='BAG')
    export.add_argument('-o', '--output', default=None, metavar='DIR',
                        help='new bag directory (default: BAG_export); it must not exist, or be '
                             'an empty directory')
    return p


def format_recovery(result) -> str:
    """What `lightstage bag recover` did: the source's problems, what was lost, what the new
    bag holds (`recover.Recovery`)."""
    from .formatting import format_size, format_time
    src, dst = result.src, result.dst
    lines = []
    if result.source_problems:
        lines.append(f'{src} is damaged or incomplete:')
        lines.extend(f'  - {p}' for p in result.source_problems)
    else:
        lines.append(f'{src}: no damage found')
    if result.unreadable:
        lines.append(f'lost in {src}: {result.unreadable} of the {result.listed} messages its '
                     'summary / metadata.yaml lists (damaged or cut off, see above)')
    elif result.listed is None and result.source_problems and not result.error:
        lines.append(f'lost in {src}: whatever was written after the damage above (it has no '
                     'intact summary or metadata.yaml that would tell how much)')
    if result.error:
        lines.append(f'RECOVERY STOPPED: {result.error}')
    info = result.info
    if info is None:
        why = (f'the copy stopped before any message reached {dst}' if result.error
               else f'{src} holds no intact message')
        lines.append(f'nothing could be recovered: {why}; no bag was written to {dst}')
        return '\n'.join(lines)
    what = (f'{info.message_count} messages on {len(info.topics)} topics into {dst} '
            f'({format_size(info.size_bytes)})')
    if not result.error:
        lines.append(f'recovered {what}')
    else:
        lines.append(f'partly recovered: {what}, those of {src} up to {format_time(info.end_ns)}; '
                     f'its summary and metadata.yaml list only those. Not copied: the rest of '
                     f'{src} ({result.source.message_count} messages in all by its info)')
    return '\n'.join(lines)


def format_export(result, renamed: dict) -> str:
    """What `lightstage bag export` did: the source's problems, what the export holds, the
    renamed types."""
    from .formatting import format_size
    lines = [f'{result.src} is damaged or incomplete (its intact messages are exported):']
    lines.extend(f'  - {p}' for p in result.source_problems)
    lines = lines if result.source_problems else []
    if result.error:
        lines.append(f'EXPORT STOPPED: {result.error}')
    info = result.info
    if info is None:
        lines.append(f'nothing exported: {result.src} holds no intact message; no bag was '
                     f'written to {result.dst}')
        return '\n'.join(lines)
    lines.append(f'exported {info.message_count} messages on {len(info.topics)} topics into '
                 f'{result.dst} ({format_size(info.size_bytes)})'
                 + (' -- partly, see EXPORT STOPPED' if result.error else ''))
    for old, new in sorted(renamed.items()):
        lines.append(f'  renamed {old} -> {new} (no type hash)')
    lines.append(f'  rosbags (Reader, AnyReader, rosbags-convert) and mcap_ros2 read {result.dst}; '
                 f'play {result.src}')
    return '\n'.join(lines)


def bag_main(argv: list[str] | None = None) -> int:
    args = bag_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from .exceptions import BagError
    from .formatting import format_info
    from .reader import BagReader
    from .recover import recover_bag
    prog = f'lightstage bag {args.command}'
    try:
        if args.command == 'info':
            info = BagReader(args.bag).info(verify=args.verify)
            print_out(json.dumps(info.to_json(), indent=2) if args.json
                      else format_info(info, args.verbose))
            return EXIT_OK if info.complete else EXIT_FAILED
        src = Path(args.bag)
        suffix = '_recovered' if args.command == 'recover' else '_export'
        dst = Path(args.output) if args.output else src.with_name(src.name.removesuffix('.mcap')
                                                                  + suffix)
        if args.command == 'export':
            from .export import export_bag
            result, renamed = export_bag(src, dst)
            print_out(format_export(result, renamed))
            if result.error or result.info is None:
                print(f'{prog}: ' + (f'the copy stopped midway; what it copied is in {dst}'
                                     if result.error else f'nothing to export from {src}'),
                      file=sys.stderr)
                return EXIT_FAILED
            return EXIT_OK
        result = recover_bag(src, dst)
        print_out(format_recovery(result))
        if result.error:
            print(f'{prog}: the copy stopped midway (see RECOVERY STOPPED above); what it '
                  f'copied is in {dst}', file=sys.stderr)
            return EXIT_FAILED
        if result.info is None:
            print(f'{prog}: nothing could be recovered from {src}; no bag was written',
                  file=sys.stderr)
            return EXIT_FAILED
        return EXIT_OK
    except BagError as exc:
        print(f'{prog}: {exc}', file=sys.stderr)
        return EXIT_USAGE
