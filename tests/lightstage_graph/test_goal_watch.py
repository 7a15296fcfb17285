"""ServerWatch: a client gives a goal up once its action server has been gone past the grace."""
import math

import pytest

from lightstage_graph.goal_watch import ServerWatch

pytestmark = pytest.mark.fast


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_a_ready_server_is_never_lost():
    clock = FakeClock()
    watch = ServerWatch(grace_s=3.0, clock=clock)
    for _ in range(10):
        assert watch.observe(True) is False
        clock.now += 10.0
    assert watch.lost_for_s == 0.0


def test_a_server_gone_past_the_grace_is_lost():
    clock = FakeClock()
    watch = ServerWatch(grace_s=3.0, clock=clock)
    assert watch.observe(True) is False
    clock.now += 1.0
    assert watch.observe(False) is False  # gone since 101.0
    clock.now += 3.0
    assert watch.lost_for_s == pytest.approx(3.0)
    assert watch.observe(False) is False  # exactly the grace: not more than it
    clock.now += 0.5
    assert watch.observe(False) is True
    assert watch.lost_for_s == pytest.approx(3.5)


def test_a_server_back_within_the_grace_starts_the_count_over():
    clock = FakeClock()
    watch = ServerWatch(grace_s=3.0, clock=clock)
    watch.observe(False)
    clock.now += 2.5
    assert watch.observe(True) is False
    assert watch.lost_for_s == 0.0
    watch.observe(False)
    clock.now += 2.5
    assert watch.observe(False) is False
    clock.now += 1.0
    assert watch.observe(False) is True


def test_a_server_never_seen_counts_from_the_first_observation():
    clock = FakeClock()
    watch = ServerWatch(grace_s=1.0, clock=clock)
    assert watch.lost_for_s == 0.0
    assert watch.observe(False) is False
    clock.now += 1.5
    assert watch.observe(False) is True


def test_zero_grace_gives_up_at_the_next_tick():
    clock = FakeClock()
    watch = ServerWatch(grace_s=0.0, clock=clock)
    assert watch.observe(False) is False
    clock.now += 0.01
    assert watch.observe(False) is True


def test_default_clock_is_monotonic():
    watch = ServerWatch()
    assert watch.grace_s == 3.0
    assert watch.observe(False) is False
    assert 0.0 <= watch.lost_for_s < 3.0


@pytest.mark.parametrize("grace_s", [-1.0, math.nan])
def test_a_grace_below_zero_or_nan_is_refused(grace_s):
    with pytest.raises(ValueError, match="grace_s"):
        ServerWatch(grace_s=grace_s)
