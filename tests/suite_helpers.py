"""Shared by the test directories that run ROS graphs (tests/nodes, tests/recording,
tests/acquisition, tests/ros): domain ids, parameter files, node processes, and an in-process
rclpy client; and the site patterns of the suite's small trained artifact (tests/conftest.py).

Imported as `suite_helpers`: pytest puts tests/ on sys.path when it loads tests/conftest.py
(the default "prepend" import mode), as it puts each test directory there for its own helpers.
"""
from __future__ import annotations

import itertools
import os
import sys
import time
from pathlib import Path

import numpy as np

from lightstage_bringup.launcher import NODE_REGISTRY, node_command
from lightstage_bringup.ros_env import ros_environment
from lightstage_bringup.supervisor import ProcessSpec, Supervisor

# two site patterns -> a per-colour artifact with classifiers for 4 and 8 images
TRAIN_SITE_PATTERNS = np.zeros((8, 2), np.float32)
TRAIN_SITE_PATTERNS[[0, 2, 5], 0] = 1
TRAIN_SITE_PATTERNS[[1, 3, 4, 6], 1] = 1

_counter = itertools.count()


def fresh_domain_id() -> int:
    """A ROS domain id for one test, 1..99 (the suite's own run uses 100..199); one counter
    for the whole run, so tests of different directories get different ids too.

    Below 100 every RTPS port (7400 + 250 * domain + ...) stays under 32768, outside the
    kernel's ephemeral port range: a socket on such a port was bound there on purpose.
    """
    return 1 + (os.getpid() * 7 + 50 + next(_counter)) % 99


def network_interfaces() -> list[str]:
    """The network interfaces of this process's network namespace (scripts/run_tests.sh's
    private one: lo). Asked of the kernel, not /sys, which shows the namespace it was mounted in."""
    import socket
    return sorted(name for _index, name in socket.if_nameindex())


def lightstage_command(*args: str) -> list[str]:
    """The argv that runs `lightstage ARGS...` (the installed CLI) in a fresh interpreter."""
    return [sys.executable, '-m', 'lightstage_bringup.cli', *args]


def write_params(path: Path, sections: dict) -> Path:
    """A ROS params YAML: {node: {param: value}}."""
    import yaml
    path.write_text(yaml.safe_dump({n: {'ros__parameters': p} for n, p in sections.items()}))
    return path


def start_nodes(supervisor: Supervisor, client: RosClient, names, domain_id: int,
                params: Path | None, timeout_s: float = 30.0) -> None:
    """Start project nodes (`lightstage up` registry names) as processes and wait until they spin.

    "Spinning" = the node's parameter service is ready, which an rclpy node offers only
    once it has finished its set-up and its executor runs.
    """
    from rcl_interfaces.srv import ListParameters
    env = ros_environment(domain_id)
    for name in names:
        supervisor.start(ProcessSpec(name, node_command(NODE_REGISTRY[name].module, name, params), env))
    clients = {n: client.node.create_client(ListParameters, f'/{n}/list_parameters') for n in names}
    deadline = time.monotonic() + timeout_s
    while True:
        dead = [p.name for p in supervisor.exited()]
        assert not dead, f'node(s) {dead} died during start-up (see their output)'
        missing = [n for n, c in clients.items() if not c.service_is_ready()]
        if not missing:
            break
        assert time.monotonic() < deadline, f'nodes {missing} did not come up in {timeout_s} s'
        client.executor.spin_once(timeout_sec=0.05)
    for c in clients.values():
        client.node.destroy_client(c)


class RosClient:
    """An rclpy node of the test process on its own context and domain, with a private
    executor: service calls, parameter sets, subscriptions."""

    def __init__(self, domain_id: int, name: str | None = None):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self.domain_id = domain_id
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name or f'test_client_{os.getpid()}', context=self.context,
                                      start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients = {}

    def call(self, srv_type, name: str, request, timeout_s: float = 30.0, wait_s: float = 10.0):
        key = (srv_type, name)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(srv_type, name)
        client = self._clients[key]
        self.spin_until(client.service_is_ready, wait_s, f'service {name}')
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        assert future.done(), f'{name} did not answer within {timeout_s} s'
        return future.result()

    def set_parameters(self, node_name: str, **values):
        """SetParameters on a node; returns its list of SetParametersResult."""
        from rcl_interfaces.srv import SetParameters
        request = SetParameters.Request(parameters=parameter_msgs(values))
        return self.call(SetParameters, f'/{node_name}/set_parameters', request).results

    def spin_until(self, predicate, timeout_s: float = 10.0, what='condition') -> None:
        """Spin until predicate() holds; ``what`` (a string, or a callable giving one when the
        time is up, e.g. to show a log as it is then) names what was awaited."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() >= deadline:
                raise AssertionError(f'timed out after {timeout_s} s waiting for '
                                     f'{what() if callable(what) else what}')
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
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

    def subscribed_by(self, topic: str, node_name: str) -> bool:
        return any(i.node_name == node_name for i in self.node.get_subscriptions_info_by_topic(topic))

    def close(self) -> None:
        import rclpy
        rclpy.shutdown(context=self.context)


def parameter_msgs(values: dict) -> list:
    """{name: value} -> rcl_interfaces Parameter messages."""
    from rclpy.parameter import Parameter
    return [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
