"""A writer's wait for the readers the ROS graph already shows, before a message that matters.

DDS discovery is asynchronous: a node's graph shows a new subscription a little before this
node's publisher has matched it, and a reliable, volatile publisher drops for that reader what
it publishes in between. Right after start-up (a classify issued as soon as the nodes are up)
that lost the first /illumination or the first image of a sequence, under load.

`ReaderMatch.wait()` compares the publisher's matched readers (`get_subscription_count`,
what the writer will deliver to) with the graph's readers of its topic (`count_subscribers`)
and, while fewer are matched, waits for them, at most `max_wait_s`. A reader that never
matches (an incompatible QoS, another message type on the same name) costs that wait once:
the graph's count it was given up on is remembered, and only a change of it waits again.
"""
from __future__ import annotations

import threading
import time

# long enough for discovery on a loaded host (it takes milliseconds idle), short beside a
# classify's timeout; a link still missing after it is left to the readers' own timeouts
LINK_WAIT_S = 2.0
_POLL_S = 0.005


class ReaderMatch:
    """Wait until `publisher` has matched every reader the graph shows on its topic."""

    def __init__(self, node, publisher, max_wait_s: float = LINK_WAIT_S,
                 clock=time.monotonic, sleep=time.sleep):
        self._node = node
        self.topic = publisher.topic_name
        self._publisher = publisher
        self.max_wait_s = float(max_wait_s)
        self._clock, self._sleep = clock, sleep
        self._given_up_at: int | None = None   # the graph's reader count a wait gave up on
        self._lock = threading.Lock()          # callers in several threads wait once, together

    def missing(self) -> int:
        """How many of the graph's readers of the topic the publisher has not matched yet."""
        graph = self._node.count_subscribers(self.topic)
        return max(0, graph - self._publisher.get_subscription_count())

    def wait(self) -> bool:
        """True once every reader in the graph is matched (at once, in the usual case); False
        after `max_wait_s` without it (logged on the node, once), or at once if the graph has
        not changed since the last wait that gave up."""
        with self._lock:
            if not self.missing():
                return True
            graph = self._node.count_subscribers(self.topic)
            if graph == self._given_up_at:
                return False
            deadline = self._clock() + self.max_wait_s
            while self._clock() < deadline:
                self._sleep(_POLL_S)
                if not self.missing():
                    self._given_up_at = None
                    return True
            self._given_up_at = self._node.count_subscribers(self.topic)
            self._node.get_logger().warning(
                f'{self.missing()} reader(s) of {self.topic} in the ROS graph not matched by this '
                f'node\'s publisher after {self.max_wait_s:g} s; publishing anyway (those readers '
                'miss it; an incompatible QoS or message type on the topic never matches)')
            return False
