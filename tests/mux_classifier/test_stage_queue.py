"""The classifier's stage queue without ROS: calls served one at a time in submission order,
and refused at once (with the reason) when they cannot be served within their time limit."""
import threading
import time

import pytest

from mux_classifier.stage_queue import StageBusy, StageQueue


def test_calls_are_served_one_at_a_time_in_submission_order():
    queue = StageQueue()
    served, inside = [], []
    release = threading.Event()

    def call(i):
        def run(remaining_s):
            inside.append(i)
            assert len(inside) == 1, inside  # never two on the stage at once
            if i == 0:
                release.wait(10.0)
            served.append(i)
            inside.remove(i)
            return i
        return run

    try:
        futures = [queue.submit(call(i), timeout_s=30.0) for i in range(50)]
        assert len(queue) == 50  # the first holds the stage, the others wait
        release.set()
        assert [f.result(timeout=30.0) for f in futures] == list(range(50))
    finally:
        queue.close()
    assert served == list(range(50))
    assert queue.served == 50 and queue.refused == 0


def test_a_call_gets_what_is_left_of_its_time_limit_and_its_errors_are_its_own():
    queue = StageQueue()
    try:
        def failing(_remaining_s):
            raise ValueError('the driver said no')
        bad = queue.submit(failing, timeout_s=5.0)
        good = queue.submit(lambda remaining_s: remaining_s, timeout_s=5.0)
        with pytest.raises(ValueError, match='the driver said no'):
            bad.result(timeout=10.0)
        assert 0 < good.result(timeout=10.0) <= 5.0
    finally:
        queue.close()


def test_a_call_that_cannot_be_served_in_time_is_refused_at_once_with_the_reason():
    now = [100.0]
    queue = StageQueue(clock=lambda: now[0])
    release, blocking = threading.Event(), threading.Event()
    try:
        # one call taught the queue that a call takes 2 s
        def two_seconds(_remaining_s):
            now[0] += 2.0
        queue.submit(two_seconds, timeout_s=10.0).result(timeout=10.0)
        assert queue.seconds_per_call == pytest.approx(2.0)

        def blocker_call(_remaining_s):
            blocking.set()
            release.wait(10.0)
        blocker = queue.submit(blocker_call, timeout_s=60.0)
        waiting = [queue.submit(lambda _r: None, timeout_s=60.0) for _ in range(3)]
        # 1 running + 3 waiting at 2 s each, + its own 2 s: 10 s > 5 s
        with pytest.raises(StageBusy) as info:
            queue.submit(lambda _r: None, timeout_s=5.0)
        assert str(info.value).startswith('4 classification(s) ahead of this one would keep the '
                                          'stage busy for about 8.0 s (2.00 s each)')
        assert 'time limit of 5 s' in str(info.value) and 'timeout_s' in str(info.value)
        late = queue.submit(lambda _r: None, timeout_s=11.0)  # 8 + 2 <= 11: queued
        assert blocking.wait(10.0)
        now[0] += 10.5  # ... but the call on the stage took longer than expected
        release.set()
        blocker.result(timeout=10.0)
        for f in waiting:
            f.result(timeout=10.0)
        with pytest.raises(StageBusy, match=r'waited 10.5 s for the stage behind 4 earlier '
                                            r'classification\(s\); 0.50 s of its 11 s time limit '
                                            r'was left, less than a call takes'):
            late.result(timeout=10.0)
    finally:
        release.set()
        queue.close()


def test_a_call_with_nothing_ahead_always_starts_and_a_full_queue_refuses():
    queue = StageQueue(max_waiting=2)
    release = threading.Event()
    try:
        queue.submit(lambda _r: time.sleep(0.0), timeout_s=1.0).result(timeout=10.0)
        running = queue.submit(lambda _r: release.wait(10.0), timeout_s=60.0)
        while len(queue._jobs):  # the worker took it
            time.sleep(0.001)
        queue.submit(lambda _r: None, timeout_s=60.0)
        queue.submit(lambda _r: None, timeout_s=60.0)
        with pytest.raises(StageBusy, match='2 classifications are already waiting for the stage'):
            queue.submit(lambda _r: None, timeout_s=60.0)
        release.set()
        running.result(timeout=10.0)
    finally:
        release.set()
        queue.close()


def test_closing_refuses_the_waiting_calls_and_lets_the_running_one_finish():
    queue = StageQueue()
    started, release = threading.Event(), threading.Event()

    def running(_r):
        started.set()
        release.wait(10.0)
        return 'done'

    first = queue.submit(running, timeout_s=60.0)
    waiting = queue.submit(lambda _r: 'never', timeout_s=60.0)
    assert started.wait(10.0)
    threading.Timer(0.2, release.set).start()
    queue.close()
    assert first.result(timeout=10.0) == 'done'
    with pytest.raises(StageBusy, match='shutting down'):
        waiting.result(timeout=1.0)
    with pytest.raises(StageBusy, match='shutting down'):
        queue.submit(lambda _r: None, timeout_s=1.0)


def test_a_waiting_call_starts_only_with_a_call_s_usual_time_and_spread_left():
    """A call whose turn comes with just over the mean time per call left would run over
    about half the time (it failed with its last image missing); it needs the mean plus four
    recent spreads (RFC 6298's retransmission timeout)."""
    now = [100.0]
    queue = StageQueue(clock=lambda: now[0])
    release, blocking = threading.Event(), threading.Event()
    try:
        for took in (1.0, 1.2, 0.8, 1.0):   # calls of about 1 s, spread about 0.2 s
            def call(_remaining_s, took=took):
                now[0] += took
            queue.submit(call, timeout_s=10.0).result(timeout=10.0)
        mean, spread = queue.seconds_per_call, queue.seconds_per_call_spread
        assert 0.9 < mean < 1.1 and 0.05 < spread < 0.5

        def blocker_call(_remaining_s):
            blocking.set()
            release.wait(10.0)
        blocker = queue.submit(blocker_call, timeout_s=60.0)
        just_over_mean = queue.submit(lambda _r: 'ran', timeout_s=10.0)
        enough = queue.submit(lambda _r: 'ran', timeout_s=60.0)
        assert blocking.wait(10.0)
        now[0] += 10.0 - (mean + 0.01)   # its turn comes with the mean + 0.01 s left
        release.set()
        blocker.result(timeout=10.0)
        with pytest.raises(StageBusy, match=r'less than a call takes \(about [\d.]+ s, up to '):
            just_over_mean.result(timeout=10.0)
        assert enough.result(timeout=10.0) == 'ran'
    finally:
        release.set()
        queue.close()
