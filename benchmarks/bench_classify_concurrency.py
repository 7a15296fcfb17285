"""Classify throughput and latency with 1, 4 and 16 concurrent clients.

Brings up driver (Python firmware simulator), sim camera and classifier as processes in a
domain id of its own (LOCALHOST discovery; run it in a private network namespace as the
tests do, e.g. `unshare --net sh -c 'ip link set lo up && .venv/bin/python ...'`), with a
naive artifact (one image per call, the sigma3 exposure of 22.5 ms) trained on a small
synthetic capture. For each client count N, N clients -- each its own participant, in its
own thread -- make --calls Classify calls one after the other, all at once; it prints the
calls per second the classifier served, the latency of a call (sent -> answered) at p50 and
p95, and how many were refused or failed. The stage serves one call at a time (the
classifier's FIFO queue), so throughput stays that of one client while latency grows with
the queue.

    .venv/bin/python benchmarks/bench_classify_concurrency.py [--clients 1 4 16] [--calls 8]
        [--timeout-s 120] [--json OUT.json]
    .venv/bin/python benchmarks/bench_classify_concurrency.py --quick   # 1 and 2 clients, 2 calls
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from lightstage_graph.graph_client import GraphClient

from _common import fresh_domain_id, parse_args, start_nodes, write_params


def _artifact(folder: Path) -> tuple[Path, Path]:
    from lightstage_physics import synth
    from lightstage_physics.capture_format import load_capture
    from mux_trainer.baselines import NaiveClassifier
    from mux_trainer.search_params import Rendering, SplitScoring
    capture = synth.generate(folder / 'capture', image_size=120, n_samples_per_class=2,
                             n_poses=3, object_types=('banana', 'orange'), n_jobs=1)
    path = folder / 'naive.npz'
    NaiveClassifier(scoring=SplitScoring(n_repeats=10), rendering=Rendering(noise='sigma3'),
                    seed=0).fit(
        load_capture(capture, downscale_to=120)).to_artifact().save(path)
    return capture, path


def _client(index: int, domain_id: int, calls: int, timeout_s: float, ready: threading.Barrier,
            out: list):
    from lightstage_interfaces.srv import Classify
    with GraphClient(domain_id, f'bench_classify_client_{index}') as graph:
        service = graph.service(Classify, '/lightstage/classify')
        graph.spin_until(service.service_is_ready, 60.0, 'the classify service')
        graph.call_until_answered(service, Classify.Request(timeout_s=timeout_s), 4, 30.0)  # matched
        ready.wait()
        for _ in range(calls):
            start = time.monotonic()
            r = graph.result(service.call_async(Classify.Request(timeout_s=timeout_s)),
                             timeout_s + 30.0, 'a Classify answer')
            out.append((start, time.monotonic(), bool(r.success), r.message))


def run_level(domain_id: int, n_clients: int, calls: int, timeout_s: float) -> dict:
    out: list = []
    ready = threading.Barrier(n_clients + 1)
    threads = [threading.Thread(target=_client, args=(i, domain_id, calls, timeout_s, ready, out))
               for i in range(n_clients)]
    for t in threads:
        t.start()
    ready.wait(timeout=120.0)
    t0 = time.monotonic()
    for t in threads:
        t.join()
    wall = time.monotonic() - t0
    latency_ms = np.array([(end - start) * 1e3 for start, end, _, _ in out])
    ok = sum(1 for *_, success, _ in out if success)
    failures = [m for *_, success, m in out if not success]
    return {'clients': n_clients, 'calls': len(out), 'served': ok, 'not_served': len(failures),
            'first_failure': failures[0] if failures else '', 'wall_s': wall,
            'calls_per_s': ok / wall, 'latency_p50_ms': float(np.percentile(latency_ms, 50)),
            'latency_p95_ms': float(np.percentile(latency_ms, 95))}


def main(argv=None) -> int:
    from lightstage_bringup.supervisor import Supervisor
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--clients', type=int, nargs='*', default=[1, 4, 16])
    p.add_argument('--calls', type=int, default=8, help='calls per client (default 8)')
    p.add_argument('--timeout-s', type=float, default=120.0, help='each call\'s time limit')
    p.add_argument('--domain-id', type=int, default=None)
    p.add_argument('--json', default='', help='also write the figures here')
    args = parse_args(p, argv, clients=[1, 2], calls=2)
    domain_id = args.domain_id if args.domain_id is not None else fresh_domain_id()
    with tempfile.TemporaryDirectory() as tmp:
        capture, artifact = _artifact(Path(tmp))
        params = write_params(Path(tmp) / 'params.yaml', {
            'camera': {'capture_dir': str(capture), 'sample': 'banana-fake/s0/p00', 'seed': 1},
            'classifier': {'artifact_path': str(artifact)}})
        rows = []
        quiet = open(os.devnull, 'w')  # the nodes' logs go to files in the temporary folder
        with GraphClient(domain_id) as graph, quiet, \
                Supervisor(stdout=quiet, stderr=quiet, log_dir=Path(tmp) / 'logs',
                           sigint_timeout_s=5.0) as supervisor:
            start_nodes(supervisor, graph, ['driver', 'camera', 'classifier'], domain_id, params)
            print(f'graph up (ROS_DOMAIN_ID={domain_id}); naive artifact, 1 image of 22.5 ms per call')
            print(f'{"clients":>7} {"calls":>6} {"served":>6} {"calls/s":>8} {"p50 ms":>8} {"p95 ms":>8}')
            for n in args.clients:
                row = run_level(domain_id, n, args.calls, args.timeout_s)
                rows.append(row)
                print(f'{n:>7} {row["calls"]:>6} {row["served"]:>6} {row["calls_per_s"]:>8.1f} '
                      f'{row["latency_p50_ms"]:>8.1f} {row["latency_p95_ms"]:>8.1f}'
                      + (f'  not served: {row["not_served"]} ({row["first_failure"]})'
                         if row['not_served'] else ''), flush=True)
            dead = [proc.name for proc in supervisor.exited()]
            print('nodes up afterwards' if not dead else f'nodes died: {dead}')
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0 if all(r['not_served'] == 0 for r in rows) and not dead else 1


if __name__ == '__main__':
    sys.exit(main())
