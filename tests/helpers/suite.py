"""Shared by the test directories that run ROS graphs (each package's folder under tests/,
which mirrors src/): domain ids, parameter files, node processes (the in-process
rclpy client is `lightstage_graph.graph_client.GraphClient`); and the site patterns of the suite's small trained artifact (tests/conftest.py).

Imported as `helpers.suite` (pytest.ini's `pythonpath = tests` puts tests/ on sys.path);
every helper module of the suite lives beside it in tests/helpers/ (see its __init__).
"""
from __future__ import annotations

import itertools
import os
import sys
import time
from pathlib import Path

import numpy as np

from lightstage_bringup.launcher import NODE_REGISTRY, node_command
from lightstage_bringup.supervisor import ProcessSpec, Supervisor
from lightstage_graph.graph_client import GraphClient, parameter_msgs  # noqa: F401 (for the tests)
from lightstage_graph.ros_env import ros_environment

from helpers.workers import xdist_worker

REPO = Path(__file__).resolve().parents[2]  # the repository: tests/ mirror its src/ packages

# two site patterns -> a per-colour artifact with classifiers for 4 and 8 images
TRAIN_SITE_PATTERNS = np.zeros((8, 2), np.float32)
TRAIN_SITE_PATTERNS[[0, 2, 5], 0] = 1
TRAIN_SITE_PATTERNS[[1, 3, 4, 6], 1] = 1

_counter = itertools.count()


def fresh_domain_id() -> int:
    """A ROS domain id for one test, 1..99 (the suite's own run uses 100..199); one counter
    for the whole run, so tests of different directories get different ids too. Workers of
    a parallel run (pytest-xdist) draw from disjoint ids (worker w: ids = 1 + w modulo the
    worker count), so two tests running at once never share a domain.

    Below 100 every RTPS port (7400 + 250 * domain + ...) stays under 32768, outside the
    kernel's ephemeral port range: a socket on such a port was bound there on purpose.
    """
    worker, workers = xdist_worker()
    return 1 + worker + workers * ((os.getpid() * 7 + 50 + next(_counter)) % (99 // workers))


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


def stage_graph_params(capture, sample: str, seed: int, artifact=None, **sections: dict) -> dict:
    """The params sections ({node: {param: value}}, for `write_params`) of a graph on the
    simulated stage: the camera showing `sample` of `capture` with noise `seed`, the classifier
    on `artifact` (10 s timeout) if one is given; `sections` add nodes or override parameters."""
    params = {'camera': {'capture_dir': str(capture), 'sample': sample, 'seed': seed}}
    if artifact is not None:
        params['classifier'] = {'artifact_path': str(artifact), 'timeout_s': 10.0}
    for node, values in sections.items():
        params[node] = {**params.get(node, {}), **values}
    return params


def start_nodes(supervisor: Supervisor, client: GraphClient, names, domain_id: int,
                params: Path | None, timeout_s: float = 30.0, wait_links: bool = True) -> None:
    """Start project nodes (`lightstage up` registry names) as processes and wait until they spin.

    "Spinning" = the node's parameter service is ready, which an rclpy node offers only
    once it has finished its set-up and its executor runs. Started together, the stage's
    links are awaited too (`wait_stage_links`), unless `wait_links` is false (what a user
    who classifies as soon as the nodes are up sees).
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
    if wait_links:
        wait_stage_links(client, names, timeout_s)


def wait_stage_links(client: GraphClient, names, timeout_s: float = 30.0) -> None:
    """Until the camera subscribes /illumination (with the driver) and the classifier
    camera/image_raw (with the camera), then a settle: a writer matches a new reader a little
    after the graph shows the reader, and what it publishes before is lost (a classify right
    after start-up lost its first frame so, under load)."""
    from lightstage_graph.names import ILLUMINATION_TOPIC, IMAGE_TOPIC, resolved
    links = {'camera': ('driver', ILLUMINATION_TOPIC), 'classifier': ('camera', resolved(IMAGE_TOPIC))}
    waited = [(reader, topic) for reader, (writer, topic) in links.items()
              if reader in names and writer in names]
    for reader, topic in waited:
        client.wait_for_subscriptions(reader, [topic], timeout_s, settle_s=0.0)
    if waited:
        client.spin_for(1.0)


def classify_on_the_stage_graph(params: Path, domain_id: int, *classify_args: str,
                                n_illumination: int = 0, wait_links: bool = True) -> tuple[dict, list]:
    """Driver, camera and classifier started as processes with `params`; one `lightstage
    classify --json` call (with `classify_args`), which must succeed; returns its answer
    and the /illumination states seen (waiting for at least `n_illumination` of them).
    `wait_links` as `start_nodes`'."""
    import json
    import subprocess

    from lightstage_interfaces.msg import IlluminationState
    client = GraphClient(domain_id)
    seen = []
    client.node.create_subscription(IlluminationState, '/illumination', seen.append, 100)
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, client, ['driver', 'camera', 'classifier'], domain_id, params,
                        wait_links=wait_links)
            p = subprocess.run([sys.executable, '-m', 'lightstage_bringup.classify_cli', '--domain-id',
                                str(domain_id), '--json', *classify_args],
                               capture_output=True, text=True, timeout=90)
            assert p.returncode == 0, p.stderr
            answer = json.loads(p.stdout)
            client.spin_until(lambda: len(seen) >= n_illumination, 10.0,
                              "the classify call's /illumination")
    finally:
        client.close()
    return answer, seen
