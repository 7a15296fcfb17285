"""ServerWatch: when a client stops waiting for an action server that went away.

A goal's result arrives only while its action server lives: a server killed mid-goal
(`kill -KILL` of the acquisition node) sends no result and no status, and a client waiting
on the result alone waits forever. The client instead observes, every so often, whether the
server is still there (`ActionClient.server_is_ready()`: the graph still shows the server's
readers and writers) and gives the goal up once the server has been gone for longer than a
grace period. The grace period covers the moments when discovery briefly shows a living
server as gone (a participant's announcement late under load), so a slow graph is not
mistaken for a dead one.

Pure (no rclpy): the clock is handed in, so tests drive the time.
"""
from __future__ import annotations

import time
from typing import Callable

__all__ = ["ServerWatch"]


class ServerWatch:
    """Observes a server's readiness and says when it has been gone for more than `grace_s`.

    `observe(server_ready)` is called at any rate; it returns True while the server has been
    not ready, in every observation since the first one that found it not ready, for more
    than `grace_s` seconds. An observation that finds it ready again starts over (a server
    restarted within the grace period is not lost; the caller that already gave up on a goal
    at the first True keeps its decision).
    """

    def __init__(self, grace_s: float = 3.0, clock: Callable[[], float] = time.monotonic):
        grace_s = float(grace_s)
        if not grace_s >= 0.0:  # also refuses nan
            raise ValueError(f"grace_s must be a number >= 0 seconds, got {grace_s!r}")
        self.grace_s = grace_s
        self._clock = clock
        self._gone_since: float | None = None

    def observe(self, server_ready: bool) -> bool:
        """Record one observation; True once the server has been gone for more than grace_s."""
        now = self._clock()
        if server_ready:
            self._gone_since = None
            return False
        if self._gone_since is None:
            self._gone_since = now
        return now - self._gone_since > self.grace_s

    @property
    def lost_for_s(self) -> float:
        """Seconds since the first of the observations that found the server gone (0.0 while
        the last observation found it ready, or before any)."""
        if self._gone_since is None:
            return 0.0
        return max(0.0, self._clock() - self._gone_since)
