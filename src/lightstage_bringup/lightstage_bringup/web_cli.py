"""`lightstage web`: the operator's page beside a running graph (docs/WEB.md).

    lightstage up driver camera classifier acquisition --params ...   # the graph
    lightstage web                                # then open http://127.0.0.1:8088/

The live camera image and the LEDs lit for it, a Classify button with the label, scores and
times and the images of each classification, the history, the driver's and camera's
/diagnostics, capture and noise calibration with progress, and the errors (a failed
classify, a lost frame, a driver in ERROR). Bound to 127.0.0.1 unless --host says otherwise:
an address beyond loopback (0.0.0.0, ::, a LAN address) needs --allow-network, and then
every request needs the token printed in the page's address (anyone on that network could
otherwise drive the stage).

Exit codes: 0 stopped by Ctrl-C / SIGTERM; 1 the server could not start (port in use);
2 bad arguments.
"""
from __future__ import annotations

import argparse
import asyncio
import os
import secrets
import signal
import sys

from lightstage_graph.ros_env import apply_ros_environment

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
DEFAULT_PORT = 8088


def port_number(text: str) -> int:
    """An argparse type: a TCP port 0..65535 (0: any free port, printed)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a port number 0..65535, got {text!r}') from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f'expected a port number 0..65535, got {port}')
    return port


def is_loopback(host: str) -> bool:
    return host in ('localhost', '::1') or host.startswith('127.')


def server_url(host: str, port: int, token: str | None = None) -> str:
    shown = f'[{host}]' if ':' in host else host
    return f'http://{shown}:{port}/' + (f'?token={token}' if token else '')


def server_parser(prog: str, description: str, default_port: int, exposes: str) -> argparse.ArgumentParser:
    """The options `lightstage web` and `lightstage view` share: where to listen, which graph."""
    p = argparse.ArgumentParser(
        prog=prog, description=description,
        epilog='exit codes: 0 stopped, 1 the server could not start, 2 bad arguments')
    p.add_argument('--port', type=port_number, default=default_port,
                   help=f'TCP port (default {default_port}; 0: any free port, printed)')
    p.add_argument('--host', default='127.0.0.1',
                   help=f'address to listen on (default 127.0.0.1: this machine only; another '
                        f'address exposes {exposes} to that network)')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID of the graph (default: $ROS_DOMAIN_ID or 0)')
    return p


def _parser() -> argparse.ArgumentParser:
    p = server_parser('lightstage web', 'Serve the operator\'s page for the running graph: live '
                      'camera image, the LEDs lit, Classify with label and scores, history, '
                      'diagnostics, capture and noise calibration with progress.',
                      DEFAULT_PORT, 'the stage\'s controls')
    p.add_argument('--history', type=int, default=30,
                   help='classifications kept with their images (default 30)')
    p.add_argument('--allow-network', action='store_true',
                   help='allow a --host beyond loopback; every request then needs the token '
                        'printed in the page\'s address (or --token)')
    p.add_argument('--token', default=None,
                   help='with --allow-network: the token to require (default: a random one, '
                        'printed); also from $LIGHTSTAGE_WEB_TOKEN')
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if not 1 <= args.history <= 1000:
            raise ValueError(f'--history must be 1..1000; got {args.history}')
        if not is_loopback(args.host) and not args.allow_network:
            raise ValueError(f'--host {args.host} is beyond this machine\'s loopback: the stage\'s '
                             'controls would be open to that network; add --allow-network to do so '
                             '(every request then needs a token), or leave --host out')
        args.token = (args.token or os.environ.get('LIGHTSTAGE_WEB_TOKEN')
                      or (secrets.token_urlsafe(24) if not is_loopback(args.host) else None))
        if args.token is not None and (len(args.token) < 16 or not args.token.isascii()):
            raise ValueError('--token must be at least 16 ASCII characters')
        apply_ros_environment(args.domain_id)  # before rclpy is imported: LOCALHOST discovery
    except ValueError as exc:
        print(f'lightstage web: {exc}', file=sys.stderr)
        return EXIT_USAGE
    return asyncio.run(serve(args))


async def serve(args) -> int:
    import rclpy
    from aiohttp import web
    from rclpy.signals import SignalHandlerOptions

    from lightstage_bringup.web_app import (KEEPALIVE_TIMEOUT_S, LOOPBACK_HOSTS, guard_connections,
                                            make_app)
    from lightstage_bringup.web_node import WebBridge, spin_in_thread
    from lightstage_bringup.web_state import PageState

    rclpy.init(args=[], domain_id=args.domain_id, signal_handler_options=SignalHandlerOptions.NO)
    state = PageState(history_size=args.history)
    node = WebBridge(state)
    node.loop = asyncio.get_running_loop()
    executor, thread = spin_in_thread(node)
    state.set_connected('ros', True)
    app = make_app(state, node, LOOPBACK_HOSTS if is_loopback(args.host) else None, token=args.token)
    runner = web.AppRunner(app, access_log=None, keepalive_timeout=KEEPALIVE_TIMEOUT_S)
    await runner.setup()
    guard_connections(runner.server)
    try:
        site = web.TCPSite(runner, args.host, args.port)
        try:
            await site.start()
        except OSError as exc:
            print(f'lightstage web: cannot listen on {args.host}:{args.port}: {exc.strerror or exc}; '
                  'choose another --port', file=sys.stderr)
            return EXIT_FAILED
        port = runner.addresses[0][1]
        if not is_loopback(args.host):
            print(f'lightstage web: WARNING: listening on {args.host}, beyond this machine: anyone '
                  'who can reach it and has the token can drive the stage; the token is in the '
                  'address below (keep it private; plain HTTP: use a trusted network only)',
                  file=sys.stderr, flush=True)
        print(f'lightstage web: the operator\'s page is at {server_url(args.host, port, args.token)} '
              f'(ROS_DOMAIN_ID={node.context.get_domain_id()}); Ctrl-C stops', flush=True)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await stop.wait()
        return EXIT_OK
    finally:
        await runner.cleanup()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
        thread.join(timeout=2.0)


if __name__ == '__main__':
    sys.exit(main())
