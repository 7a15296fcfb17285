"""The recorder node: every topic of the graph, as received, into an MCAP bag.

    ros2 run lightstage_recording recorder --ros-args -p output_dir:=bags/run1
    lightstage record -o bags/run1            # the same, with command-line options

It watches the graph (every ``discovery_period_s``) and subscribes *raw* (serialized CDR,
no deserialization) to each new topic the selection takes -- including the service event
topics ``<service>/_service_event`` of services with introspection on, so the Classify and
ApplyPatterns calls themselves are in the bag -- with a QoS matched to what the topic's
publishers offer (`recording.subscription_qos`). Each message is written with its receive
time as log time and its send time as publish time (`writer.BagWriter`, through
`recording.Recording`); the chunk in progress is handed to the OS every ``flush_period_s``
(no fsync), so a recorder that is killed loses at most that much. With ``max_bag_size_bytes``
/ ``max_bag_duration_s`` the bag is split into files ``NAME_0.mcap``, ``NAME_1.mcap``, ... as
rosbag2 splits it, and ``max_bag_files`` keeps only the newest files. SIGINT / SIGTERM (or
``max_duration_s``) close the bag: summary, footer, ``metadata.yaml``, fsynced; the recorder
then prints what it recorded. A write error (disk full) stops the recording: the bag is
closed with what it holds, the error is printed, exit code 1.
"""
from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path

import rclpy
from lightstage_graph.names import RECORDER_NODE
from lightstage_graph.params import (boolean, declare_parameters, floating, integer, string,
                                     string_array)
from lightstage_graph.ros_env import apply_node_environment_and_say
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future

from .bag_ros import from_rclpy_qos, new_published_topics, to_rclpy_qos
from .exceptions import BagError
from .layout import default_bag_name
from .msg_definitions import is_service_event
from .recording import Recording, TopicSelector, subscription_qos
from .writer import COMPRESSIONS, MIN_SPLIT_SIZE_BYTES, BagWriter

class RecorderError(Exception):
    """A recorder that cannot start; the message says what to change."""


PARAMETERS = {
    'output_dir': ('', string('bag directory to create (must not exist, or be an empty '
                              'directory); empty: rosbag2_YYYY_MM_DD-HH_MM_SS in the working '
                              'directory', read_only=True)),
    'topics': (Parameter.Type.STRING_ARRAY, string_array(
        'record only these topics (full names); unset: every topic the other parameters take',
        read_only=True)),
    'include_regex': ('', string('record topics whose name matches this regular expression '
                                 '(with topics: either selects)', read_only=True)),
    'exclude_regex': ('', string('never record topics whose name matches this regular '
                                 'expression', read_only=True)),
    'record_services': (True, boolean('record service introspection events '
                                      '(<service>/_service_event topics)', read_only=True)),
    'include_hidden_topics': (False, boolean('also record other hidden topics (a name part '
                                             'starting with _, e.g. action feedback)',
                                             read_only=True)),
    'discovery_period_s': (0.5, floating('how often the graph is checked for new topics [s]',
                                         0.05, 60.0, read_only=True)),
    'qos_depth': (100, integer('keep-last depth of the recorder\'s subscriptions [messages]',
                               1, 100_000, read_only=True)),
    'compression': ('lz4', string(f'chunk compression: {" | ".join(COMPRESSIONS)}',
                                  read_only=True)),
    'chunk_size_bytes': (1 << 20, integer('chunk size of the MCAP file [bytes]', 1024, 1 << 30,
                                          read_only=True)),
    'flush_period_s': (1.0, floating('the chunk in progress is handed to the OS this often [s] '
                                     '(no fsync); a killed recorder loses at most this much',
                                     0.05, 600.0, read_only=True)),
    'max_duration_s': (0.0, floating('stop and close the bag after this long [s]; 0: until '
                                     'SIGINT / SIGTERM', 0.0, 1e7, read_only=True)),
    # splitting, as ros2 bag record's --max-bag-size / --max-bag-duration: a recorder left on
    # for days then writes NAME_0.mcap, NAME_1.mcap, ... and with max_bag_files keeps the newest
    'max_bag_size_bytes': (0, integer('start the next file of the bag before this one reaches '
                                      'this size [bytes] (rosbag2\'s max_bag_size); 0: no limit, '
                                      f'else at least {MIN_SPLIT_SIZE_BYTES}', 0, 1 << 62,
                                      read_only=True)),
    'max_bag_duration_s': (0.0, floating('start the next file of the bag once this one spans '
                                         'this long [s] (rosbag2\'s max_bag_duration); 0: no '
                                         'limit', 0.0, 1e9, read_only=True)),
    'max_bag_files': (0, integer('keep only the newest this many files of the bag, deleting the '
                                 'oldest as a new one starts (metadata.yaml and the log say so); '
                                 '0: keep every file', 0, 1_000_000, read_only=True)),
}


class RecorderNode(Node):
    def __init__(self, node_name: str = RECORDER_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        try:
            topics = self.p('topics')
        except ParameterUninitializedException:
            topics = None
        try:
            self.selector = TopicSelector(tuple(topics) if topics else None,
                                          self.p('include_regex'), self.p('exclude_regex'),
                                          self.p('record_services'), self.p('include_hidden_topics'))
        except ValueError as exc:
            raise RecorderError(str(exc)) from None
        output = self.p('output_dir') or default_bag_name()
        try:
            self.writer = BagWriter(Path(output), compression=self.p('compression'),
                                    chunk_size_bytes=self.p('chunk_size_bytes'),
                                    library='lightstage_recording recorder',
                                    max_bag_size_bytes=self.p('max_bag_size_bytes'),
                                    max_bag_duration_s=self.p('max_bag_duration_s'),
                                    max_bag_files=self.p('max_bag_files'),
                                    on_event=lambda text: self.get_logger().info(text))
        except BagError as exc:
            raise RecorderError(str(exc)) from None
        self.recording = Recording(self.writer)
        self.done = Future()
        self._recording: dict[str, object] = {}
        self._skipped: dict[str, str] = {}  # topic -> why it is not recorded (reported once)
        self._started = time.monotonic()
        self._lock = threading.Lock()
        self._finished = False
        self._error_reported = False
        self.get_logger().info(f'recording to {self.writer.path}')
        self.create_timer(self.p('discovery_period_s'), self._discover)
        self.create_timer(self.p('flush_period_s'), self._flush)
        if self.p('max_duration_s') > 0:
            self.create_timer(self.p('max_duration_s'), self._time_up)
        self._discover()

    # ------------------------------------------------------------------ topics
    def _discover(self) -> None:
        if self._finished or self.recording.stopped:
            return
        known = self._recording.keys() | self._skipped.keys()
        for topic, type_name, cls, publishers, problem in new_published_topics(self, known, self.selector):
            if problem:
                self._skip(topic, problem)
                continue
            offered = [from_rclpy_qos(p.qos_profile) for p in publishers]
            type_hash = str(publishers[0].topic_type_hash)
            if not self.recording.add_topic(topic, type_name, offered,
                                            type_hash=type_hash if type_hash.startswith('RIHS')
                                            else None):
                self._stop_on_error()
                return
            qos = subscription_qos(offered, self.p('qos_depth'))
            self._recording[topic] = self.create_subscription(
                cls, topic, self._writer_callback(topic), to_rclpy_qos(qos), raw=True)
            what = 'service events' if is_service_event(topic, type_name) else type_name
            self.get_logger().info(f'recording {topic} ({what}; {qos.reliability}, {qos.durability})')

    def _skip(self, topic: str, why: str) -> None:
        self._skipped[topic] = why
        self.get_logger().warning(f'not recording {topic}: {why}')

    def _writer_callback(self, topic: str):
        receive = self.recording.receive

        def on_message(data: bytes, info: dict) -> None:
            if not receive(topic, data, info):
                self._stop_on_error()
        return on_message

    def _flush(self) -> None:
        if not self.recording.flush():
            self._stop_on_error()

    def _stop_on_error(self) -> None:
        """After a write error: say so once and end the recording (`run` closes the bag)."""
        if not self.recording.error or self._error_reported:
            return
        self._error_reported = True
        self.get_logger().error(f'recording stopped: {self.recording.error}')
        if not self.done.done():
            self.done.set_result(False)

    @property
    def recorded_topics(self) -> list[str]:
        return list(self._recording)

    # ------------------------------------------------------------------ ending
    def _time_up(self) -> None:
        if not self.done.done():
            self.get_logger().info(f'max_duration_s {self.p("max_duration_s"):g} reached')
            self.done.set_result(True)

    def finish(self) -> str:
        """Close the bag (idempotent) and return the report of what was recorded."""
        with self._lock:
            if self._finished:
                return ''
            self._finished = True
        for sub in self._recording.values():
            self.destroy_subscription(sub)
        self.recording.close()
        return self.report()

    def report(self) -> str:
        return self.recording.report(time.monotonic() - self._started, self.selector,
                                     self._skipped)


def run(args: list[str] | None = None, parameter_overrides: list[Parameter] | None = None,
        drain_s: float = 0.2) -> int:
    """Record until SIGINT / SIGTERM or max_duration_s; 0 on success, 1 when writing failed
    (disk full: the bag is closed with what it holds), 2 when it cannot start.

    On SIGINT / SIGTERM the recorder first takes what has already arrived (until nothing came
    for ``drain_s``, at most 2 s: the end of the last classification is not cut off), then
    closes the bag. rclpy's own signal handlers are not installed, since they would shut the
    context down before that.
    """
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = RecorderNode(parameter_overrides=parameter_overrides or [])
    except RecorderError as exc:
        print(f'recorder: {exc}', file=sys.stderr, flush=True)
        rclpy.try_shutdown()
        return 2
    stop = threading.Event()
    previous = {}

    def on_signal(signum, _frame):
        node.get_logger().info(f'{signal.Signals(signum).name} received: closing the bag')
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, on_signal)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop.is_set() and not node.done.done() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        deadline = time.monotonic() + 2.0
        idle_since = time.monotonic()
        while (rclpy.ok() and not node.recording.stopped and time.monotonic() - idle_since < drain_s
               and time.monotonic() < deadline):
            before = node.writer.message_count
            executor.spin_once(timeout_sec=0.02)
            if node.writer.message_count != before:
                idle_since = time.monotonic()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        report = node.finish()
        print(report, flush=True)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if node.recording.error:
        print(f'recorder: recording stopped: {node.recording.error}', file=sys.stderr, flush=True)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    apply_node_environment_and_say(RECORDER_NODE)  # however it was started (`ros2 run` too)
    return run(sys.argv if argv is None else argv)


if __name__ == '__main__':
    sys.exit(main())
