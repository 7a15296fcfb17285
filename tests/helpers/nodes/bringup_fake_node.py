"""A tiny rclpy node standing in for a project node in the launcher tests.

Parameters (settable from a params YAML): `greeting` (printed on stdout at start),
`die_after_s` (> 0: exit with `exit_code` after that long), `ignore_sigint` (stay up after
SIGINT, so the launcher has to escalate to SIGTERM), `exit_code_on_stop` (exit status when
stopped by a signal, to play a node that fails its shutdown), `spin_delay_s` (in the graph,
its parameter services there, but not spinning for that long: a node busy in its set-up).
"""
import faulthandler
import signal
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException


def main() -> int:
    rclpy.init()
    # a node the launcher has to escalate to SIGTERM shows where it was stuck (then
    # rclpy's own handler, installed by init, runs as before)
    faulthandler.register(signal.SIGTERM, chain=True)
    node = rclpy.create_node('bringup_fake_node')
    greeting = node.declare_parameter('greeting', 'hello').value
    die_after_s = node.declare_parameter('die_after_s', 0.0).value
    exit_code = node.declare_parameter('exit_code', 0).value
    exit_code_on_stop = node.declare_parameter('exit_code_on_stop', 0).value
    if node.declare_parameter('ignore_sigint', False).value:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    spin_delay_s = node.declare_parameter('spin_delay_s', 0.0).value
    print(f'greeting={greeting} name={node.get_name()}', flush=True)
    time.sleep(spin_delay_s)
    node.get_logger().info('fake node up')
    t0 = time.monotonic()
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.05)
            if die_after_s > 0 and time.monotonic() - t0 > die_after_s:
                print(f'exiting with {exit_code} as asked', flush=True)
                return exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # a signal that lands inside spin_once can shut the context down under it, which
        # surfaces as an rcl error instead of ExternalShutdownException: that is a stop too
        if rclpy.ok():
            raise
    print('fake node stopped', flush=True)
    return exit_code_on_stop


if __name__ == '__main__':
    sys.exit(main())
