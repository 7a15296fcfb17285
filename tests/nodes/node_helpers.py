"""Helpers of the node tests: domain ids, node processes, an in-process ROS client."""
import itertools
import os
import time
from pathlib import Path

import numpy as np

from lightstage_bringup.launcher import node_command
from lightstage_bringup.ros_env import ros_environment
from lightstage_bringup.supervisor import ProcessSpec, Supervisor

TRAIN_SITE_PATTERNS = np.zeros((8, 2), np.float32)
TRAIN_SITE_PATTERNS[[0, 2, 5], 0] = 1
TRAIN_SITE_PATTERNS[[1, 3, 4, 6], 1] = 1

MODULES = {'driver': 'lightstage_driver.driver_node', 'camera': 'lightstage_camera.camera_node',
           'classifier': 'mux_classifier.classifier_node'}
_counter = itertools.count()


def fresh_domain_id() -> int:
    """A ROS domain id in 1..99 for one test (the suite's own are 100..199)."""
    return 1 + (os.getpid() * 7 + 50 + next(_counter)) % 99


def write_params(path: Path, sections: dict) -> Path:
    """A ROS params YAML: {node: {param: value}}."""
    import yaml
    path.write_text(yaml.safe_dump({n: {'ros__parameters': p} for n, p in sections.items()}))
    return path


def start_nodes(supervisor: Supervisor, client: 'RosClient', names, domain_id: int,
                params: Path | None, timeout_s: float = 30.0) -> None:
    """Start project nodes (registry names) as processes and wait until they spin.

    "Spinning" = the node's parameter service is ready, which an rclpy node offers only
    once it has finished its set-up and its executor runs.
    """
    from rcl_interfaces.srv import ListParameters
    env = ros_environment(domain_id)
    for name in names:
        supervisor.start(ProcessSpec(name, node_command(MODULES[name], name, params), env))
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
    """Service calls, parameter sets and subscriptions from the test process, in its own context."""

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(f'node_test_client_{os.getpid()}', context=self.context,
                                      start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients = {}

    def call(self, srv_type, name: str, request, timeout_s: float = 30.0, wait_s: float = 10.0):
        key = (srv_type, name)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(srv_type, name)
        client = self._clients[key]
        deadline = time.monotonic() + wait_s
        while not client.service_is_ready():
            assert time.monotonic() < deadline, f'service {name} not available after {wait_s} s'
            self.executor.spin_once(timeout_sec=0.05)
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        assert future.done(), f'{name} did not answer within {timeout_s} s'
        return future.result()

    def set_parameters(self, node_name: str, **values):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        request = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        return self.call(SetParameters, f'/{node_name}/set_parameters', request).results

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)

    def close(self) -> None:
        import rclpy
        rclpy.shutdown(context=self.context)
