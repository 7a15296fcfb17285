#!/usr/bin/env python3
"""Replaying the demo's stage session into an observing classifier while a recorder runs:
how many of the session's classifications come back, per replay, for the classifier as
shipped (one executor thread) and on rclpy's MultiThreadedExecutor (4 threads, the node's
executor the node ran on before), the two alternating in one run.

Each replay starts the classifier with the demo's replay parameters and a recorder (as
`lightstage up classifier` does), plays the bag's /illumination and /camera/image_raw as the
demo prints (`lightstage play ... --delay-s 1`), and counts the /lightstage/result messages
against the recorded calls of `out/demo/demo_results.json` (greedy). A reader of its own
counts the images played, so a loss is the classifier's, not the player's.

    make demo     # once: out/demo/stage_session, replay_params.yaml, demo_results.json
    .venv/bin/python benchmarks/bench_replay_labels.py [--runs 4] [--demo-dir out/demo]

`--quick` (one replay per arm) without --demo-dir replays the bundled session instead
(bags/sim_session: 4 classifications, into its own bags/sim_session_classifier.npz), so it
needs no `make demo`.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, parse_args, write_params

VENV_BIN = Path(sys.executable).parent
MULTI_THREADED = ('import sys; from lightstage_graph.spin import init_node, spin_until_stopped; '
                  'from rclpy.executors import MultiThreadedExecutor; '
                  'from mux_classifier.classifier_node import ClassifierNode; '
                  'init_node(sys.argv); '
                  'sys.exit(spin_until_stopped(ClassifierNode(), MultiThreadedExecutor(num_threads=4)))')


def start_graph(arm: str, params: Path, domain_id: int, workdir: Path, env: dict) -> list:
    """The classifier and a recorder: `lightstage up` for the shipped node, else the node's
    class on a 4-thread executor beside `lightstage record`."""
    lightstage = str(VENV_BIN / 'lightstage')
    if arm == 'shipped':
        argv = [[lightstage, 'up', 'classifier', '--params', str(params), '--domain-id', str(domain_id)]]
    else:
        argv = [[sys.executable, '-c', MULTI_THREADED, '--ros-args', '-r', '__node:=classifier',
                 '--params-file', str(params)],
                [lightstage, 'record', '-o', str(workdir / f'bag_{time.monotonic_ns()}')]]
    return [subprocess.Popen(a, cwd=workdir, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL) for a in argv]


def replay(arm: str, session: Path, params: Path, domain_id: int, want: int,
           workdir: Path) -> tuple[int, int]:
    """One replay: (labels received, images a deep reader of its own received)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from lightstage_interfaces.msg import ClassificationResult
    from lightstage_graph.ros_env import ros_environment
    env = ros_environment(domain_id)
    procs = start_graph(arm, params, domain_id, workdir, env)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    node = rclpy.create_node('bench_replay_labels', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    labels, images = [], []
    node.create_subscription(ClassificationResult, '/lightstage/result', labels.append, 100)
    node.create_subscription(Image, '/camera/image_raw', lambda _m: images.append(1),
                             QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
    try:
        deadline = time.monotonic() + 60
        while node.count_publishers('/lightstage/result') == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        play = subprocess.Popen(
            [str(VENV_BIN / 'lightstage'), 'play', str(session), '--topics',
             '/illumination', '/camera/image_raw', '--wait-for', '/illumination',
             '/camera/image_raw', '--delay-s', '1', '--domain-id', str(domain_id)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while play.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        deadline = time.monotonic() + 15
        while len(labels) < want and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            p.wait(60)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    return len(labels), len(images)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--demo-dir', type=Path, help='`make demo`\'s output (default out/demo)')
    p.add_argument('--runs', type=int, default=4, help='replays per arm (default 4)')
    p.add_argument('--arms', nargs='*', default=['shipped', 'multi_threaded'],
                   choices=['shipped', 'multi_threaded'])
    p.add_argument('--domain-id', type=int, default=57)
    args = parse_args(p, argv, runs=1)
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(args.domain_id))
    totals = {arm: [] for arm in args.arms}
    with tempfile.TemporaryDirectory(prefix='bench_replay_') as tmp:
        if args.quick and args.demo_dir is None:
            session = ROOT / 'bags' / 'sim_session'
            params = write_params(Path(tmp) / 'replay_params.yaml', {'classifier': {
                'artifact_path': str(ROOT / 'bags' / 'sim_session_classifier.npz'),
                'classify_observed': True}})
            calls = [None] * 4  # the bundled session's classifications (bags/README.md)
        else:
            demo = (args.demo_dir or Path('out/demo')).resolve()
            session, params = demo / 'stage_session', demo / 'replay_params.yaml'
            calls = json.loads((demo / 'demo_results.json').read_text())['on_stage']['greedy']['calls']
        for run in range(args.runs):
            for arm in args.arms:
                got, images = replay(arm, session, params, args.domain_id, len(calls), Path(tmp))
                totals[arm].append(got)
                print(f'run {run} {arm:15s} {got:3d} of {len(calls)} labels '
                      f'({images} images played)', flush=True)
    for arm, got in totals.items():
        full = sum(g == len(calls) for g in got)
        print(f'{arm:15s} {sum(got)} of {len(calls) * len(got)} labels; {full} of {len(got)} '
              f'replays complete; per replay {got}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
