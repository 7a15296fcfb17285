"""Shared by the tests/ros tests: domain ids, node processes through the supervisor, and an
in-process rclpy client on its own context."""
from __future__ import annotations

import contextlib
import io
import itertools
import os
import time
from pathlib import Path

from lightstage_bringup.launcher import GraphWatcher, node_command
from lightstage_bringup.ros_env import ros_environment
from lightstage_bringup.supervisor import ProcessSpec, Supervisor

HERE = Path(__file__).resolve().parent
_counter = itertools.count()


def fresh_domain_id() -> int:
    """A ROS domain id for one test, 1..99 (the suite's own run uses 100..199).

    Below 100 every RTPS port (7400 + 250 * domain + ...) stays under 32768, outside the
    kernel's ephemeral port range: a socket on such a port was bound there on purpose.
    """
    return 1 + (os.getpid() * 7 + 50 + next(_counter)) % 99


def child_environment(domain_id: int, **overrides: str) -> dict[str, str]:
    env = ros_environment(domain_id)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(HERE), env.get('PYTHONPATH', '')) if p)
    env.update(overrides)
    return env


@contextlib.contextmanager
def running_nodes(nodes: dict[str, str], domain_id: int, timeout_s: float = 20.0,
                  wrap: list[str] | None = None, params_file: str | None = None,
                  **env_overrides: str):
    """Start `{ros node name: module}` as separate processes (as `lightstage up` does), wait
    until each spins, yield the Supervisor; on exit stop them and check they stopped cleanly.

    `wrap` prefixes every command (e.g. strace); `params_file` is a ROS parameters YAML
    keyed by these node names. Children's output is kept in `sup.output`.
    """
    out = io.StringIO()
    sup = Supervisor(stdout=out, stderr=out, sigint_timeout_s=5, sigterm_timeout_s=2)
    sup.output = out
    env = child_environment(domain_id, **env_overrides)
    try:
        for name, module in nodes.items():
            sup.start(ProcessSpec(name, [*(wrap or []), *node_command(module, name, params_file)], env))
        with GraphWatcher(domain_id) as graph:
            missing, dead = graph.wait_for(list(nodes), timeout_s, sup)
        assert dead is None, f'{dead} died during start-up:\n{out.getvalue()}'
        assert not missing, f'{missing} not up after {timeout_s} s:\n{out.getvalue()}'
        yield sup
    finally:
        reports = sup.shutdown()
    unclean = [str(r) for r in reports if not r.clean]
    assert not unclean, f'nodes did not stop cleanly: {unclean}\n{out.getvalue()}'


class RosClient:
    """An rclpy node on its own context and domain, with a private executor."""

    def __init__(self, domain_id: int, name: str = 'test_client'):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout_s: float = 10.0, what: str = 'condition') -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            assert time.monotonic() < deadline, f'timed out after {timeout_s} s waiting for {what}'
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def result(self, future, timeout_s: float = 10.0, what: str = 'a response'):
        self.spin_until(future.done, timeout_s, what)
        return future.result()

    def call_until_answered(self, client, request, attempts: int = 4, per_try_s: float = 3.0):
        """Call an idempotent service until it answers: the first response can be lost while
        the reply path (server -> this client) is still being matched, which
        `service_is_ready()` does not cover. Use it to warm a connection up."""
        for _ in range(attempts):
            future = client.call_async(request)
            deadline = time.monotonic() + per_try_s
            while not future.done() and time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.05)
            if future.done():
                return future.result()
            client.remove_pending_request(future)
        raise AssertionError(f'no response after {attempts} calls of {per_try_s} s each')

    def close(self) -> None:
        self._rclpy.shutdown(context=self.context)
