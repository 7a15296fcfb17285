"""Time from starting two node processes to "all spinning" as seen by GraphWatcher, with
and without renewing the watcher's participant (side by side, alternating, one run).

    .venv/bin/python benchmarks/bench_graph_watcher.py [rounds]   (after make test / make demo)

"""
import io
import statistics
import sys
import time

from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'tests'))  # the tests' helpers package
from helpers.bringup import child_environment
from lightstage_bringup.launcher import GraphWatcher, node_command
from lightstage_bringup.supervisor import ProcessSpec, Supervisor

NODES = {'a': 'bringup_fake_node', 'b': 'bringup_fake_node'}


def one_run(domain_id: int, renew_s: float) -> float:
    env = child_environment(domain_id)
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


def main() -> None:
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    results = {'renew every 1 s (default)': [], 'no renewal': []}
    for i in range(2 * rounds):
        label = list(results)[i % 2]
        results[label].append(one_run(domain_id=61 + i, renew_s=1.0 if i % 2 == 0 else 1e9))
    for label, times in results.items():
        print(f'{label:28s} median {statistics.median(times):.2f} s  '
              f'(min {min(times):.2f}, max {max(times):.2f}, n={len(times)})')


if __name__ == '__main__':
    main()
