"""Time from starting two node processes to "all spinning" as seen by GraphWatcher, with
and without renewing the watcher's participant (side by side, alternating, one run). The
nodes are rclpy nodes that only spin (benchmarks/_idle_node.py).

    .venv/bin/python benchmarks/bench_graph_watcher.py [rounds]   (after make test / make demo)
"""
import argparse
import io
import os
import statistics
import time
from pathlib import Path

from lightstage_bringup.launcher import GraphWatcher, node_command
from lightstage_bringup.supervisor import ProcessSpec, Supervisor
from lightstage_graph.ros_env import ros_environment

from _common import fresh_domain_id, parse_args

NODES = {'a': '_idle_node', 'b': '_idle_node'}
HERE = Path(__file__).resolve().parent


def one_run(domain_id: int, renew_s: float) -> float:
    env = ros_environment(domain_id)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(HERE), env.get('PYTHONPATH')) if p)
    sup = Supervisor(stdout=io.StringIO(), stderr=io.StringIO())
    t0 = time.monotonic()
    try:
        for name, module in NODES.items():
            sup.start(ProcessSpec(name, node_command(module, name), env))
        with GraphWatcher(domain_id, renew_s=renew_s) as graph:
            missing, dead = graph.wait_for(list(NODES), 30.0, sup)
        assert not missing and dead is None, (missing, dead)
        return time.monotonic() - t0
    finally:
        sup.shutdown()


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('rounds', type=int, nargs='?', default=5, help='runs of each (default 5)')
    rounds = parse_args(p, argv, rounds=1).rounds
    results = {'renew every 1 s (default)': [], 'no renewal': []}
    for i in range(2 * rounds):
        label = list(results)[i % 2]
        results[label].append(one_run(domain_id=fresh_domain_id(), renew_s=1.0 if i % 2 == 0 else 1e9))
    for label, times in results.items():
        print(f'{label:28s} median {statistics.median(times):.2f} s  '
              f'(min {min(times):.2f}, max {max(times):.2f}, n={len(times)})')


if __name__ == '__main__':
    main()
