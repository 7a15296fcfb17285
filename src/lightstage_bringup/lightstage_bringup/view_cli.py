"""`lightstage view`: the running graph, live, in Foxglove or Lichtblick (docs/WEB.md).

    lightstage up driver camera classifier --params ...   # the graph
    lightstage view                  # then in Foxglove: Open connection -> Foxglove WebSocket
                                     # ws://127.0.0.1:8765, and import the stage's layout

Serves every topic of the graph (camera images, /illumination, /lightstage/result,
/diagnostics, the service calls' events, ...) over the Foxglove WebSocket protocol
(`view_server`: subprotocol foxglove.websocket.v1 or foxglove.sdk.v1), as CDR with ros2msg
schemas. Bound to 127.0.0.1 unless --host says otherwise; connections from other websites'
pages (Origin) or through other host names (Host) are refused.

Exit codes: 0 stopped by Ctrl-C / SIGTERM; 1 the server could not start (port in use);
2 bad arguments.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading

from lightstage_bringup.view_server import APP_ORIGINS
from lightstage_bringup.web_cli import is_loopback, server_parser
from lightstage_graph.ros_env import apply_ros_environment

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
DEFAULT_PORT = 8765  # Foxglove's default for a WebSocket connection


def _parser() -> argparse.ArgumentParser:
    p = server_parser('lightstage view', 'Serve the running graph over the Foxglove WebSocket '
                      'protocol, for Foxglove or Lichtblick: images, illumination, results, '
                      'diagnostics, service calls.', DEFAULT_PORT, 'the graph')
    p.add_argument('--include', default='', metavar='REGEX',
                   help='serve only topics matching this regular expression')
    p.add_argument('--exclude', default='', metavar='REGEX',
                   help='never serve topics matching this regular expression')
    p.add_argument('--no-services', action='store_true',
                   help='leave out the service calls (<service>/_service_event topics)')
    p.add_argument('--allow-origin', action='append', default=[], metavar='ORIGIN',
                   help='also accept browser pages from this origin (e.g. https://viewer.example.org; '
                        'repeatable). Accepted without it: programs (no Origin), pages on this '
                        'machine (http://localhost:*, http://127.0.0.1:*), the desktop apps '
                        '(file://) and ' + ', '.join(APP_ORIGINS))
    p.add_argument('--allow-host', action='append', default=[], metavar='NAME',
                   help='also accept connections addressed to this host name (repeatable; the '
                        'loopback names and --host are accepted)')
    return p


def main(argv: list[str] | None = None) -> int:
    from lightstage_recording.recording import TopicSelector
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        selector = TopicSelector(None, args.include, args.exclude, services=not args.no_services)
        apply_ros_environment(args.domain_id)  # before rclpy is imported: LOCALHOST discovery
    except ValueError as exc:
        print(f'lightstage view: {str(exc).replace("include_regex", "--include").replace("exclude_regex", "--exclude")}',
              file=sys.stderr)
        return EXIT_USAGE
    return serve(args, selector)


def serve(args, selector) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from lightstage_bringup.view_channels import layout_path, server_metadata
    from lightstage_bringup.view_node import ViewNode
    from lightstage_bringup.view_server import FoxgloveServer, Guard

    wildcard = args.host in ('0.0.0.0', '::', '0', '')
    guard = Guard(hosts=tuple(args.allow_host) + (() if wildcard else (args.host,)),
                  origins=APP_ORIGINS + tuple(args.allow_origin))
    server = FoxgloveServer('lightstage', metadata=server_metadata(), guard=guard,
                            report=lambda text: print(f'lightstage view: {text}', file=sys.stderr,
                                                      flush=True))
    try:
        port = server.start(args.host, args.port)
    except OSError as exc:
        print(f'lightstage view: cannot listen on {args.host}:{args.port}: {exc}; choose another '
              '--port', file=sys.stderr)
        return EXIT_FAILED
    if not is_loopback(args.host):
        print(f'lightstage view: listening on {args.host}: the graph is visible to that network'
              + ('; clients must address this machine by a name given with --allow-host'
                 if wildcard and not args.allow_host else ''), file=sys.stderr)
    rclpy.init(args=[], domain_id=args.domain_id, signal_handler_options=SignalHandlerOptions.NO)
    node = ViewNode(selector, server)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    layout = layout_path()
    print(f'lightstage view: Foxglove WebSocket at ws://{args.host}:{port} '
          f'(ROS_DOMAIN_ID={node.context.get_domain_id()})'
          + (f'; the stage\'s layout: {layout}' if layout else '') + '; Ctrl-C stops', flush=True)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    finally:
        server.stop()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
