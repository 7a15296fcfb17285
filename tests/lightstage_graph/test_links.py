"""ReaderMatch: a writer waits for the readers the graph shows, briefly, and only when needed."""
import pytest

from lightstage_graph.links import ReaderMatch

pytestmark = pytest.mark.fast


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds


class FakeLogger:
    def __init__(self):
        self.warnings = []

    def warning(self, text):
        self.warnings.append(text)


class FakeNode:
    """The graph's reader count; the publisher matches them `match_after_s` later."""

    def __init__(self, clock, graph_readers, match_after_s):
        self.clock, self.graph_readers, self.match_after_s = clock, graph_readers, match_after_s
        self.logger = FakeLogger()

    def count_subscribers(self, topic):
        assert topic == '/camera/image_raw'
        return self.graph_readers

    def get_logger(self):
        return self.logger


class FakePublisher:
    topic_name = '/camera/image_raw'

    def __init__(self, node, never_matched=0):
        self.node, self.never_matched = node, never_matched

    def get_subscription_count(self):
        node = self.node
        if node.clock.now < node.match_after_s:
            return 0
        return node.graph_readers - self.never_matched


def reader_match(graph_readers, match_after_s, never_matched=0):
    clock = FakeClock()
    node = FakeNode(clock, graph_readers, match_after_s)
    match = ReaderMatch(node, FakePublisher(node, never_matched), max_wait_s=2.0,
                        clock=clock, sleep=clock.sleep)
    return match, node, clock


def test_matched_readers_cost_no_wait():
    match, node, clock = reader_match(graph_readers=2, match_after_s=0.0)
    assert match.wait() and clock.now == 0.0


def test_no_reader_in_the_graph_costs_no_wait():
    match, node, clock = reader_match(graph_readers=0, match_after_s=5.0)
    assert match.wait() and clock.now == 0.0


def test_a_reader_the_graph_shows_is_waited_for_until_matched():
    match, node, clock = reader_match(graph_readers=1, match_after_s=0.3)
    assert match.missing() == 1
    assert match.wait()
    assert 0.3 <= clock.now < 0.32
    assert match.missing() == 0 and not node.logger.warnings


def test_a_reader_that_never_matches_costs_the_wait_once_and_is_logged():
    match, node, clock = reader_match(graph_readers=2, match_after_s=0.0, never_matched=1)
    assert not match.wait()
    assert 2.0 <= clock.now < 2.02
    assert len(node.logger.warnings) == 1
    assert '1 reader(s) of /camera/image_raw' in node.logger.warnings[0]
    # the same graph: no second wait, no second warning
    before = clock.now
    assert not match.wait()
    assert clock.now == before and len(node.logger.warnings) == 1


def test_a_change_of_the_graph_after_a_give_up_is_waited_for_again():
    match, node, clock = reader_match(graph_readers=2, match_after_s=0.0, never_matched=1)
    assert not match.wait()
    node.graph_readers = 3          # a new reader appears; the one that never matches stays
    node.match_after_s = clock.now + 0.5
    match._publisher.never_matched = 0
    start = clock.now
    assert match.wait()
    assert 0.5 <= clock.now - start < 0.52
