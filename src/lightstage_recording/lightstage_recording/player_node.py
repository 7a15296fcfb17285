"""The player node: a bag's messages back into the graph, as recorded.

    ros2 run lightstage_recording player --ros-args -p bag:=bags/sim_classify
    lightstage play bags/sim_classify --topics /illumination /camera/image_raw --wait-for /camera/image_raw

Every message is published as the recorded CDR bytes (`Publisher.publish(bytes)`, nothing is
deserialized) on a publisher with the recorded QoS (`recording.playback_qos`), at the
recorded log times scaled by ``rate``. ``start_offset_s`` skips the bag's first seconds,
``loop`` plays it again and again. With ``wait_for_subscribers`` playback starts only once
each of those topics has a matched subscriber (a reliable, volatile topic delivers nothing
to readers that match later), and ``delay_s`` later (the subscriber may match the player a
little after the player matched it). Service event topics, ``/rosout`` and ``/parameter_events``
are left out unless ``topics`` names them (``exclude_regex``). A damaged bag plays every
intact message and says what was lost. At the end the player waits until reliable
subscribers have acknowledged everything, then exits.
"""
from __future__ import annotations

import signal
import sys
import threading
import time

import rclpy
from lightstage_graph.names import PLAYER_NODE
from lightstage_graph.params import (boolean, declare_parameters, floating, integer, string,
                                     string_array)
from lightstage_graph.ros_env import apply_node_environment_and_say
from rclpy.duration import Duration
from rclpy.exceptions import InvalidParameterValueException, ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter

from .bag_ros import message_class, to_rclpy_qos
from .exceptions import BagError
from .reader import BagReader
from .recording import DEFAULT_PLAY_EXCLUDE, playback_delay_s, playback_qos, select_play_topics

class PlayerError(Exception):
    """A bag that cannot be played as asked; the message says what to change."""


# the topics every node publishes itself: a remap onto one with another type would fail in rcl
NODE_OWN_TOPICS = {'/rosout': 'rcl_interfaces/msg/Log',
                   '/parameter_events': 'rcl_interfaces/msg/ParameterEvent'}


def check_remaps(rules: list[str], types: dict[str, str], played: list[str]) -> dict[str, str]:
    """The --remap rules FROM:=TO of a playback as {bag topic: topic it is published on};
    PlayerError naming the rule for: a name that is not a ROS topic name, a FROM the bag does
    not hold or that is not played, a FROM remapped twice, two topics onto one, and a topic
    onto another of a different type (played from the bag, or every node's own)."""
    import difflib

    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name
    remapped: dict[str, str] = {}
    for rule in rules:
        source, sep, target = rule.partition(':=')
        if not sep or not source or not target:
            raise PlayerError(f'--remap {rule!r}: write FROM:=TO, e.g. '
                              '/image_raw:=/camera/image_raw')
        for name in (source, target):
            try:
                validate_topic_name(name)
            except InvalidTopicNameException as exc:
                raise PlayerError(f'--remap {rule!r}: {name!r} is not a ROS topic name '
                                  f'({str(exc).splitlines()[0]}); use letters, digits, _ and /')                     from None
        source, target = ('/' + n.lstrip('/') for n in (source, target))
        if source not in types:
            close = difflib.get_close_matches(source, list(types), n=1)
            hint = f'did you mean {close[0]}?' if close else f'it has {", ".join(sorted(types))}'
            raise PlayerError(f'--remap {rule!r}: the bag has no topic {source} ({hint})')
        if source not in played:
            raise PlayerError(f'--remap {rule!r}: {source} is not played (playing: '
                              f'{", ".join(played)}); add it to --topics')
        if source in remapped and remapped[source] != target:
            raise PlayerError(f'--remap {rule!r}: {source} is already remapped to '
                              f'{remapped[source]}; give one rule per topic')
        remapped[source] = target
    destination = {t: remapped.get(t, t) for t in played}
    onto: dict[str, str] = {}
    for topic, target in destination.items():
        if target in onto:
            raise PlayerError(f'--remap: {onto[target]} and {topic} would both be published on '
                              f'{target}; remap one of them elsewhere')
        onto[target] = topic
        # every node's own topics, and those the recorded graph had: a topic of another type
        # there fails in rcl (one process) or never matches (another)
        other = NODE_OWN_TOPICS.get(target, types.get(target))
        if other is not None and other != types[topic]:
            raise PlayerError(f'--remap: {topic} ({types[topic]}) onto {target}, which carries '
                              f'{other}; choose another topic')
    return destination


PARAMETERS = {
    'bag': ('', string('bag directory (metadata.yaml + .mcap) or .mcap file to play',
                       read_only=True)),
    'topics': (Parameter.Type.STRING_ARRAY, string_array(
        'play only these topics; unset: every recorded topic not matching exclude_regex',
        read_only=True)),
    'exclude_regex': (DEFAULT_PLAY_EXCLUDE, string('topics left out unless named in topics',
                                                   read_only=True)),
    'rate': (1.0, floating('playback speed factor (2.0: twice as fast)', 0.01, 100.0,
                           read_only=True)),
    'start_offset_s': (0.0, floating('skip the first seconds of the bag [s]', 0.0, 1e7,
                                     read_only=True)),
    'loop': (False, boolean('play the bag again and again until stopped', read_only=True)),
    'wait_for_subscribers': (Parameter.Type.STRING_ARRAY, string_array(
        'start only once each of these topics has a matched subscriber', read_only=True)),
    'wait_timeout_s': (10.0, floating('give up when a subscriber of wait_for_subscribers has '
                                      'not matched after this long [s]', 0.0, 3600.0,
                                      read_only=True)),
    # a match seen from the publisher's side does not mean the subscriber has matched the
    # publisher yet; a volatile subscriber loses what arrives before it has
    'delay_s': (0.0, floating('wait this long before the first message, after any '
                              'wait_for_subscribers [s]', 0.0, 3600.0, read_only=True)),
    'qos_depth': (100, integer('keep-last depth of publishers whose recorded depth is unknown '
                               '[messages]', 1, 100_000, read_only=True)),
    'ack_timeout_s': (5.0, floating('at the end, wait this long for reliable subscribers to '
                                    'acknowledge everything [s]', 0.0, 600.0, read_only=True)),
}


class PlayerNode(Node):
    def __init__(self, node_name: str = PLAYER_NODE, **kwargs):
        super().__init__(node_name, **kwargs)
        self.p = declare_parameters(self, PARAMETERS)
        if not self.p('bag'):
            raise PlayerError('no bag given; set the bag parameter (-p bag:=DIR) or use '
                              '`lightstage play DIR`')
        try:
            self.reader = BagReader(self.p('bag'))
            self.info = self.reader.info()
            self.topics = select_play_topics(self.info.topics, self._array('topics'),
                                             self.p('exclude_regex'))
        except (BagError, ValueError) as exc:
            raise PlayerError(str(exc)) from None
        for problem in self.info.problems:
            self.get_logger().warning(f'{problem}; playing every intact message')
        self.publishers_by_topic = {}
        for topic in self.topics:
            t = self.info.topics[topic]
            try:
                cls = message_class(t.type)
            except ImportError as exc:
                raise PlayerError(f'cannot play {topic}: {exc}') from None
            qos = playback_qos(t.offered_qos, self.p('qos_depth'))
            try:
                self.publishers_by_topic[topic] = self.create_publisher(cls, topic,
                                                                        to_rclpy_qos(qos))
            except Exception as exc:  # noqa: BLE001 - rcl's refusal, e.g. a remap onto another type
                raise PlayerError(f'cannot publish {topic} ({t.type}) where it is remapped to: '
                                  f'{str(exc).splitlines()[0]}') from None
        self.stop = threading.Event()
        self.played = 0

    def _array(self, name: str) -> list[str] | None:
        try:
            value = self.p(name)
        except ParameterUninitializedException:
            return None
        return list(value) if value else None

    def wait_for_subscribers(self) -> None:
        topics = self._array('wait_for_subscribers') or []
        unknown = [t for t in topics if t not in self.publishers_by_topic]
        if unknown:
            raise PlayerError(f'wait_for_subscribers names {", ".join(unknown)}, which this '
                              f'playback does not publish (playing: {", ".join(self.topics)})')
        deadline = time.monotonic() + self.p('wait_timeout_s')
        while not self.stop.is_set():
            missing = [t for t in topics if self.publishers_by_topic[t].get_subscription_count() == 0]
            if not missing:
                return
            if time.monotonic() >= deadline:
                raise PlayerError(f'no subscriber matched {", ".join(missing)} within '
                                  f'{self.p("wait_timeout_s"):g} s; start the node that should '
                                  'receive them (same ROS_DOMAIN_ID) or raise wait_timeout_s')
            time.sleep(0.01)

    def play_once(self) -> int:
        """One pass over the bag at the recorded timing; returns the messages published."""
        offset_ns = int(self.p('start_offset_s') * 1e9)
        start_ns = self.info.start_ns + offset_ns
        rate = float(self.p('rate'))
        t0 = None
        count = 0
        messages = self.reader.messages(self.topics, start_ns=start_ns)
        while True:
            try:
                m = next(messages, None)
            except BagError as exc:  # a chunk beyond the memory limit, found while playing
                raise PlayerError(f'stopped after {self.played + count} messages: {exc}') from None
            if m is None or self.stop.is_set():
                break
            if t0 is None:
                t0 = time.monotonic()
            delay = t0 + playback_delay_s(m.log_time_ns, start_ns, rate) - time.monotonic()
            if delay > 0 and self.stop.wait(delay):
                break
            self.publishers_by_topic[m.topic].publish(m.data)
            count += 1
        self.played += count
        return count

    def wait_for_acks(self) -> bool:
        timeout = Duration(nanoseconds=int(self.p('ack_timeout_s') * 1e9))
        return all(p.wait_for_all_acked(timeout) for p in self.publishers_by_topic.values())


def run(args: list[str] | None = None, parameter_overrides: list[Parameter] | None = None) -> int:
    """Play the bag; 0 when played, 1 on a playback error, 2 when the bag / options are bad.

    SIGINT / SIGTERM only set the node's stop flag: rclpy's own handler would shut the
    context down while this thread publishes (which crashed the player, SIGSEGV, once in a
    fresh-clone test run); the context is shut down here, after the last publish.
    """
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    own_signals = threading.current_thread() is threading.main_thread()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO if own_signals
                   else SignalHandlerOptions.ALL)
    except Exception as exc:  # noqa: BLE001 - rcl's parse error of a remap rule, a traceback else
        print(f'player: bad ROS arguments {args[1:]}: {str(exc).splitlines()[0]}',
              file=sys.stderr, flush=True)
        return 2
    try:
        node = PlayerNode(parameter_overrides=parameter_overrides or [])
    except (PlayerError, InvalidParameterValueException) as exc:
        print(f'player: {exc}', file=sys.stderr, flush=True)
        rclpy.try_shutdown()
        return 2
    previous = {}
    if own_signals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda _signum, _frame: node.stop.set())
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=_spin, args=(executor, node), daemon=True)
    spinner.start()
    rc = 0
    started = time.monotonic()
    interrupted = False
    try:
        node.wait_for_subscribers()
        log = node.get_logger()
        if not node.stop.wait(node.p('delay_s')):
            log.info(f'playing {len(node.topics)} topics of {node.reader.path} at rate '
                     f'{node.p("rate"):g}: {", ".join(node.topics)}')
            while True:
                node.play_once()
                if not node.p('loop') or node.stop.is_set():
                    break
        interrupted = node.stop.is_set()
        if not interrupted and not node.wait_for_acks():
            log.warning(f'not every reliable subscriber acknowledged the last messages within '
                        f'{node.p("ack_timeout_s"):g} s')
    except PlayerError as exc:
        print(f'player: {exc}', file=sys.stderr, flush=True)
        rc = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        interrupted = True
    finally:
        node.stop.set()
        if rc == 0:
            problems = node.reader.problems
            print(f'played {node.played} messages on {len(node.topics)} topics in '
                  f'{time.monotonic() - started:.1f} s from {node.reader.path}'
                  + (' (stopped before the end)' if interrupted else '')
                  + (f' (damaged bag: {"; ".join(problems)})' if problems else ''), flush=True)
        executor.shutdown(timeout_sec=2.0)
        spinner.join(timeout=5.0)
        node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return rc


def _spin(executor, node: PlayerNode) -> None:
    """Serve the node's parameter services while the main thread plays; if the spinner ends
    (the context shut down from elsewhere), playback stops."""
    from rclpy.executors import ExternalShutdownException
    try:
        executor.spin()
    except (ExternalShutdownException, KeyboardInterrupt):
        pass
    except Exception:  # noqa: BLE001 - a dying spinner must still stop playback
        pass
    finally:
        node.stop.set()


def main(argv: list[str] | None = None) -> int:
    apply_node_environment_and_say(PLAYER_NODE)  # however it was started (`ros2 run` too)
    return run(sys.argv if argv is None else argv)


if __name__ == '__main__':
    sys.exit(main())
