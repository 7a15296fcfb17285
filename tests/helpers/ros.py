"""Shared by the tests that start node processes from the ROS side (ros2 run, cross-process
interfaces, the trainer on Dask): node processes through the supervisor, checked by the graph
as `lightstage up` does (domain ids and the in-process client are helpers.suite)."""
from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

from lightstage_bringup.launcher import GraphWatcher, node_command
from lightstage_graph.ros_env import ros_environment
from lightstage_bringup.supervisor import ProcessSpec, Supervisor

# The stand-in node scripts (run as modules by name: `ros_fake_driver_node`, ...)
NODE_SCRIPTS = Path(__file__).resolve().parent / 'nodes'


def child_environment(domain_id: int, **overrides: str) -> dict[str, str]:
    env = ros_environment(domain_id)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(NODE_SCRIPTS), env.get('PYTHONPATH', '')) if p)
    env.update(overrides)
    return env


@contextlib.contextmanager
def running_nodes(nodes: dict[str, str | list[str]], domain_id: int, timeout_s: float = 20.0,
                  wrap: list[str] | None = None, params_file: str | None = None,
                  env: dict[str, str] | None = None, **env_overrides: str):
    """Start `{ros node name: module}` as separate processes (as `lightstage up` does), wait
    until each spins, yield the Supervisor; on exit stop them and check they stopped cleanly.

    A value may also be a whole command line (e.g. `ros2 run`'s), run as given. `wrap`
    prefixes every command (e.g. strace); `params_file` is a ROS parameters YAML keyed by
    these node names; `env` replaces the children's environment (default: the project's ROS
    environment with the stand-in node scripts on PYTHONPATH). Children's output is kept in `sup.output`.
    """
    out = io.StringIO()
    sup = Supervisor(stdout=out, stderr=out, sigint_timeout_s=5, sigterm_timeout_s=2)
    sup.output = out
    env = child_environment(domain_id, **env_overrides) if env is None else env
    try:
        for name, module in nodes.items():
            command = module if isinstance(module, list) else node_command(module, name, params_file)
            sup.start(ProcessSpec(name, [*(wrap or []), *command], env))
        with GraphWatcher(domain_id) as graph:
            missing, dead = graph.wait_for(list(nodes), timeout_s, sup)
        assert dead is None, f'{dead} died during start-up:\n{out.getvalue()}'
        assert not missing, f'{missing} not up after {timeout_s} s:\n{out.getvalue()}'
        yield sup
    finally:
        reports = sup.shutdown()
    unclean = [str(r) for r in reports if not r.clean]
    assert not unclean, f'nodes did not stop cleanly: {unclean}\n{out.getvalue()}'

