"""Starting a node and running it until it is stopped: the one `main()` body of the
project's nodes (as in ros2/examples).

    def main(argv=None):
        init_node(sys.argv if argv is None else argv)
        return spin_until_stopped(TrainerNode(), MultiThreadedExecutor(num_threads=2))

`init_node` is `rclpy.init` in the project's ROS environment, however the node was started
(`ros2 run` from a shell that did not source the setup file included), and logs what that
changed. Ctrl-C (SIGINT), SIGTERM and an external `rclpy.shutdown()` are all a stop: the
node is destroyed (a node that holds hardware releases it in its `destroy_node`), rclpy
shut down, exit code 0.

The stop is ordered here, not by rclpy's signal handler: that one shuts the context (and
rcl's logging) down from its own thread at once, under whatever the node's callbacks and
threads are doing at that moment, which killed a driver node with SIGSEGV (1 CI run).
Here a signal only asks the spin loop to end; callbacks in flight get `CALLBACK_GRACE_S`
to finish, then the node is destroyed and rclpy shut down, in that order, in one thread.
A node with long work of its own (the trainer's and the acquisition's goals) defines
`stop_work()`: called at the stop, it asks that work to end and returns a callable saying
whether it has, which the grace waits for too.
A second signal does not wait: it interrupts what runs (KeyboardInterrupt) and the node is
destroyed at once.
"""
from __future__ import annotations

import signal
import threading
import time

import rclpy
import rclpy.logging
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import (SignalHandlerOptions, get_current_signal_handlers_options,
                           uninstall_signal_handlers)

from .params import ParameterError, params_files_of, read_params_file
from .ros_env import apply_node_environment

# how long an idle spin waits before it looks at the stop flag: the latency of a stop
STOP_POLL_S = 0.25
# how long callbacks in flight at a stop (a classify request, an image) may take to finish
CALLBACK_GRACE_S = 5.0
# spinning on after the work has ended, for the replies it scheduled
SETTLE_S = 0.2
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def init_node(args: list[str] | None = None) -> None:
    """`rclpy.init(args=args)` after giving this process the project's ROS environment
    (LOCALHOST discovery, the Fast DDS profile: `ros_env`); logs what that changed."""
    message = apply_node_environment()
    for path in params_files_of(args):  # rcl's own parse error is a traceback without the line
        try:
            read_params_file(path)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
    rclpy.init(args=args)
    if message:
        rclpy.logging.get_logger('ros_env').info(message)


def spin_until_stopped(node: Node, executor: Executor | None = None) -> int:
    """Spin `node` on `executor` (default: single-threaded) until stopped, then let the
    callbacks in flight finish, destroy the node and shut rclpy down; returns 0."""
    executor = executor if executor is not None else SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()
    previous_handlers = _stop_on_signals(stop)
    try:
        while not stop.is_set() and executor.context.ok():
            executor.spin_once(timeout_sec=STOP_POLL_S)
        _finish_work(executor, node, CALLBACK_GRACE_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # a context shut down by someone else while spin builds its wait set surfaces as an
        # RCLError, not ExternalShutdownException (ros2/rclpy#1166): a stop all the same
        if rclpy.ok():
            raise
    finally:
        try:
            executor.shutdown(timeout_sec=0)
            node.destroy_node()
            rclpy.try_shutdown()
        finally:
            _restore_signals(previous_handlers)
    return 0


def _stop_on_signals(stop: threading.Event) -> dict:
    """The first SIGINT / SIGTERM sets `stop`, a second one raises KeyboardInterrupt. Only the
    main thread can handle signals: elsewhere (a node run in a test's thread) rclpy's
    handler, if installed, stays in charge. Returns the handlers to restore."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    if get_current_signal_handlers_options() != SignalHandlerOptions.NO:
        uninstall_signal_handlers()
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}

    def request_stop(_signum, _frame):
        if stop.is_set():
            # a second signal: interrupt what still runs (a long callback in this thread);
            # the node is still destroyed, so hardware is released
            raise KeyboardInterrupt
        stop.set()

    for sig in STOP_SIGNALS:
        signal.signal(sig, request_stop)
    return previous


def _restore_signals(previous: dict) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)
    previous.clear()


def _finish_work(executor: Executor, node: Node, timeout_s: float) -> None:
    """Ask the node's own work to end (`stop_work`, if it has one) and spin on until it has
    and no callback is in flight (a coroutine awaiting a worker's result needs the executor
    to resume it), for at most `timeout_s`."""
    stop_work = getattr(node, 'stop_work', None)
    work_done = stop_work() if callable(stop_work) else (lambda: True)
    # rclpy 7.1's Executor.shutdown(timeout_sec) means to wait for the callbacks and does not
    # (it tests the flag it has just set); its work tracker counts them
    tracker = getattr(executor, '_work_tracker', None)

    def idle() -> bool:
        return (tracker is None or tracker.wait(0)) and work_done()

    deadline = time.monotonic() + timeout_s
    while not idle() and time.monotonic() < deadline and executor.context.ok():
        executor.spin_once(timeout_sec=0.05)
    if not idle():
        node.get_logger().warning(f'stopping with work still running after {timeout_s:g} s')
        return
    # what the work's end scheduled (an action's result goes out in a task of its own)
    settle = time.monotonic() + SETTLE_S
    while time.monotonic() < settle and executor.context.ok():
        executor.spin_once(timeout_sec=0.05)
