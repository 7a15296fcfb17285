"""What the benchmark scripts share (imported as `_common`: a script run as a file has its own
folder on sys.path): the quick mode `make bench` runs, the small capture it measures on, and
the ROS graph the graph benchmarks start (project nodes as processes, a client participant).

Not a benchmark itself: `make bench` and tests/test_benchmarks.py skip files named `_*.py`.
"""
from __future__ import annotations

import argparse
import itertools
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
QUICK_CAPTURE = ROOT / '.cache' / 'bench_quick_capture'
QUICK_HELP = 'a small run of the same measurement, as `make bench` runs it (sets '


def parse_args(parser: argparse.ArgumentParser, argv=None, **quick) -> argparse.Namespace:
    """`parser.parse_args(argv)` with a `--quick` flag: a small run of every part of the
    script (what `make bench` runs, so that each script is run to the end after a change).
    `quick` holds the defaults it sets (keyword = the option's dest); options given on the
    command line still win. `quick_capture=True` in the namespace when the script's
    `--capture` should default to `small_capture()`."""
    shown = ', '.join(f'--{k.replace("_", "-")} {" ".join(map(str, v)) if isinstance(v, (list, tuple)) else v}'
                      for k, v in quick.items() if not isinstance(v, bool) or v)
    parser.add_argument('--quick', action='store_true',
                        help=QUICK_HELP + (shown or 'nothing else') + ')')
    given = sys.argv[1:] if argv is None else list(argv)
    if '--quick' in given:
        parser.set_defaults(**quick)
    return parser.parse_args(given)


def default_capture() -> Path:
    """The synthetic dataset of `make demo` (10 classes x 20 poses), generated once into
    .cache/bench_synth (`lightstage synth`'s defaults, about 2-3 minutes on 2 cores)."""
    path = ROOT / '.cache' / 'bench_synth'
    if not (path / 'rig.yaml').exists():
        from lightstage_physics.synth import generate
        print(f'generating the synthetic dataset into {path} ...', flush=True)
        generate(path)
    return path


def capture_or_default(capture: str | None, quick: bool) -> Path:
    """--capture if given, else the small capture in a quick run, else the default dataset."""
    if capture:
        return Path(capture)
    return small_capture() if quick else default_capture()


def small_capture() -> Path:
    """A small synthetic capture for quick runs (2 object types, real and fake, 2 physical
    samples x 3 poses, 120 px; a few seconds to render, kept in .cache for the next script)."""
    if not (QUICK_CAPTURE / 'rig.yaml').exists():
        from lightstage_physics.synth import generate
        print(f'generating a small capture into {QUICK_CAPTURE} ...', flush=True)
        generate(QUICK_CAPTURE, image_size=120, n_samples_per_class=2, n_poses=3,
                 object_types=('banana', 'orange'), n_jobs=1)
    return QUICK_CAPTURE


_domain_ids = itertools.count()


def fresh_domain_id() -> int:
    """A ROS domain id for one graph, 1..99 (every RTPS port below the ephemeral range), from
    this process's id so that two benchmarks running at once rarely share one."""
    return 1 + (os.getpid() * 7 + next(_domain_ids)) % 99


def write_params(path: Path, sections: dict) -> Path:
    """A ROS params YAML: {node: {param: value}}."""
    import yaml
    path.write_text(yaml.safe_dump({n: {'ros__parameters': p} for n, p in sections.items()}))
    return path


# reader -> (writer, topic): the links of the simulated stage that must match before a call
STAGE_LINKS = {'camera': ('driver', 'illumination'), 'classifier': ('camera', 'image')}


def start_nodes(supervisor, client, names, domain_id: int, params: Path | None,
                timeout_s: float = 30.0) -> None:
    """Start project nodes (`lightstage up` registry names) as processes, wait until each
    spins (`GraphWatcher.wait_for`, as `lightstage up` waits), then until the stage's links
    among them have matched (the camera subscribes /illumination, the classifier the
    camera's images) and a second more: a writer matches a new reader a little after the
    graph shows it, and what it publishes before is lost."""
    from lightstage_bringup.launcher import NODE_REGISTRY, GraphWatcher, node_command
    from lightstage_bringup.supervisor import ProcessSpec
    from lightstage_graph.names import ILLUMINATION_TOPIC, IMAGE_TOPIC, resolved
    from lightstage_graph.ros_env import ros_environment
    env = ros_environment(domain_id)
    for name in names:
        supervisor.start(ProcessSpec(name, node_command(NODE_REGISTRY[name].module, name, params), env))
    with GraphWatcher(domain_id) as graph:
        missing, dead = graph.wait_for(list(names), timeout_s, supervisor)
    if dead or missing:
        raise RuntimeError(f'node {dead} died during start-up' if dead else
                           f'nodes {missing} did not come up in {timeout_s} s')
    topics = {'illumination': ILLUMINATION_TOPIC, 'image': resolved(IMAGE_TOPIC)}
    waited = [(reader, topics[topic]) for reader, (writer, topic) in STAGE_LINKS.items()
              if reader in names and writer in names]
    for reader, topic in waited:
        client.wait_for_subscriptions(reader, [topic], timeout_s, settle_s=0.0)
    if waited:
        client.spin_for(1.0)


def bag_results(bag, topic: str = '/lightstage/result') -> list:
    """The ClassificationResult messages of a bag's `topic`, in bag order."""
    from lightstage_interfaces.msg import ClassificationResult
    from lightstage_recording import BagReader
    from rclpy.serialization import deserialize_message
    return [deserialize_message(m.data, ClassificationResult) for m in BagReader(bag).messages([topic])]
