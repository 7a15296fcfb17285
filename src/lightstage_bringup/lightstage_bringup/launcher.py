"""`lightstage up`: start project nodes as separate processes and keep them running.

Each node runs in its own process (`python -c "from MODULE import main; main()" --ros-args
-r __node:=NAME ...`) with the project's ROS environment (`ros_env.ros_environment`). The
launcher waits until every node is discoverable in the ROS graph and spinning, prints one
`graph up: ...` line, forwards the children's output prefixed with their names, and stops
them all in order on Ctrl-C / SIGTERM or as soon as one of them dies.

The graph records itself by default: a recorder node (`lightstage_recording.recorder_node`,
its section of the params file) writes every topic and service call to a new bag
`--bag-dir/rosbag2_YYYY_MM_DD-HH_MM_SS` (default `out/bags/`); `--no-record` leaves it out.

Exit codes: 0 clean run and shutdown; 1 a node died or did not stop cleanly; 2 bad
arguments (unknown node, module missing, unreadable params file); 3 a node did not appear
in the ROS graph within --timeout-s.

Process supervision lives in `supervisor.py` (no rclpy); only the graph check uses rclpy.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from lightstage_bringup.supervisor import ProcessSpec, Supervisor
from lightstage_graph.exits import describe_exit
from lightstage_graph.params import read_params_file
from lightstage_graph.names import (ACQUISITION_NODE, CAMERA_NODE, CLASSIFIER_NODE, DRIVER_NODE,
                                    PLAYER_NODE, RECORDER_NODE, TRAINER_NODE)
from lightstage_graph.ros_env import apply_ros_environment, ros_environment

EXIT_OK, EXIT_NODE_FAILED, EXIT_USAGE, EXIT_NOT_DISCOVERED = 0, 1, 2, 3


@dataclass(frozen=True)
class NodeEntry:
    """A node the launcher can start: the module whose `main()` runs it."""
    module: str
    description: str = ''


# name -> node; the name is also the ROS node name (remapped with __node:=NAME) and the
# key of the node's section in the params YAML.
NODE_REGISTRY: dict[str, NodeEntry] = {
    DRIVER_NODE: NodeEntry('lightstage_driver.driver_node', 'LED stage driver (serial or simulated firmware)'),
    CAMERA_NODE: NodeEntry('lightstage_camera.camera_node', 'camera (simulated: renders the sample under each pattern)'),
    CLASSIFIER_NODE: NodeEntry('mux_classifier.classifier_node', 'classifier (Classify service, /result topic)'),
    TRAINER_NODE: NodeEntry('mux_trainer.trainer_node', 'trainer (Train action)'),
    ACQUISITION_NODE: NodeEntry('lightstage_camera.acquisition_node',
                                'model capture and noise calibration (CaptureModel, CalibrateNoise actions)'),
    RECORDER_NODE: NodeEntry('lightstage_recording.recorder_node',
                             'records every topic and service call to an MCAP bag (recorder section of the params)'),
    PLAYER_NODE: NodeEntry('lightstage_recording.player_node', 'plays a bag into the graph (set its bag parameter)'),
}
DEFAULT_NODES = (DRIVER_NODE, CAMERA_NODE, CLASSIFIER_NODE)
RECORDER = RECORDER_NODE  # started as well unless --no-record
DEFAULT_BAG_DIR = Path('out') / 'bags'
# A recorder that runs by default must not fill the disk over days of use: its bag is split
# into 1 GiB files and only the newest 10 are kept (at most ~10 GiB per `lightstage up`),
# unless the params file's recorder section sets these itself
DEFAULT_RECORDING_LIMITS = {'max_bag_size_bytes': 1 << 30, 'max_bag_files': 10}


def node_command(module: str, name: str, params_file: str | None = None,
                 extra_ros_args: list[str] | None = None) -> list[str]:
    """The argv that runs `module.main()` as ROS node `name` in a fresh interpreter.

    `-c` instead of `-m`: node modules expose `main()` (their ros2-run wrappers call it)
    and need no `if __name__ == '__main__'` block for this to work.
    """
    code = f'import sys; from {module} import main; sys.exit(main())'
    argv = [sys.executable, '-c', code, '--ros-args', '-r', f'__node:={name}']
    if params_file:
        argv += ['--params-file', str(params_file)]
    return argv + list(extra_ros_args or [])


def _parser() -> argparse.ArgumentParser:
    known = '\n'.join(f'  {n:<11} {e.module}  ({e.description})' for n, e in NODE_REGISTRY.items())
    p = argparse.ArgumentParser(
        prog='lightstage up',
        description='Start light-stage nodes as separate processes, wait until they are '
                    'discoverable in the ROS graph, forward their output, and stop them all '
                    'on Ctrl-C or when one of them dies.',
        epilog=f'nodes:\n{known}\n\nexit codes: 0 ok, 1 a node died / did not stop cleanly, '
               '2 bad arguments, 3 a node was not discoverable in time',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('nodes', nargs='*', metavar='NODE',
                   help=f'nodes to start (default: {" ".join(DEFAULT_NODES)})')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID for the nodes and the graph check (default: $ROS_DOMAIN_ID or 0)')
    p.add_argument('--params', metavar='FILE.yaml', default=None,
                   help='ROS parameters file passed to every node (--params-file)')
    p.add_argument('--no-record', action='store_true',
                   help='do not start the recorder (by default the graph records every topic and '
                        'service call to an MCAP bag under --bag-dir)')
    p.add_argument('--bag-dir', metavar='DIR', default=str(DEFAULT_BAG_DIR),
                   help='folder of the recorded bags; each run writes a new '
                        'DIR/rosbag2_YYYY_MM_DD-HH_MM_SS (default: %(default)s)')
    p.add_argument('--log-dir', metavar='DIR', default=None,
                   help='write each node\'s output to DIR/NAME.log and ROS log files to DIR (ROS_LOG_DIR)')
    p.add_argument('--timeout-s', type=float, default=20.0,
                   help='how long to wait for all nodes to appear in the ROS graph [s] (default 20)')
    p.add_argument('--exit-after-up', action='store_true',
                   help='stop all nodes as soon as the graph is up (for tests and demos)')
    p.add_argument('--node', action='append', default=[], metavar='NAME=MODULE',
                   help='add or replace a registry entry: start MODULE.main() as node NAME')
    p.add_argument('--sigint-timeout-s', type=float, default=5.0,
                   help='grace time after SIGINT before SIGTERM at shutdown [s]')
    p.add_argument('--sigterm-timeout-s', type=float, default=3.0,
                   help='grace time after SIGTERM before SIGKILL at shutdown [s]')
    return p


def _registry_with_overrides(overrides: list[str]) -> dict[str, NodeEntry]:
    registry = dict(NODE_REGISTRY)
    for item in overrides:
        name, sep, module = item.partition('=')
        if not sep or not name or not module:
            raise ValueError(f'--node {item!r}: expected NAME=MODULE, e.g. --node driver=lightstage_driver.driver_node')
        registry[name] = NodeEntry(module, 'from --node')
    return registry


def _module_exists(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # parent package missing, or a bad name
        return False


class GraphWatcher:
    """A hidden rclpy node on its own context that watches the ROS graph for given nodes.

    With LOCALHOST discovery, Fast DDS finds a participant that starts *after* this one
    only at this one's next periodic announcement (measured: ~3.5 s), while one that
    already exists is found in ~0.1 s. So while expected nodes are missing from the graph,
    the watcher re-creates its participant, which announces it afresh: after `renew_s`,
    then after twice that, and so on (a renewal drops calls in flight, so it backs off, and
    the nodes' spinning is checked only once none is missing from the graph).
    Its own context makes it usable inside a process that uses rclpy otherwise.
    """

    def __init__(self, domain_id: int, renew_s: float = 1.0):
        self.domain_id = domain_id
        self.renew_s = renew_s
        self._graph = None
        self.node = None

    def _open(self) -> None:
        from lightstage_graph.graph_client import GraphClient

        # (no rclpy signal handlers: the caller's own SIGINT/SIGTERM handlers stay in charge)
        self._graph = GraphClient(self.domain_id, f'_lightstage_up_{os.getpid()}',
                                  enable_rosout=False, use_global_arguments=False)
        self.node = self._graph.node
        self._executor = self._graph.executor
        self._opened_at = time.monotonic()

    def _close(self) -> None:
        if self._graph is not None:
            self._graph.close()  # also ends the executor and the node
            self._graph = None

    def __enter__(self) -> 'GraphWatcher':
        apply_ros_environment()  # LOCALHOST discovery and the profile for this participant
        self._open()
        return self

    def __exit__(self, *exc) -> None:
        self._close()

    def wait_for(self, names: list[str], timeout_s: float, supervisor: Supervisor | None = None,
                 stop_event: threading.Event | None = None) -> tuple[list[str], str | None]:
        """Poll the graph until every name in `names` is a node in it and is spinning.

        "Spinning" = its parameter service answers a `list_parameters` call, which an rclpy
        node does only once its executor runs, i.e. after its set-up code; a node without
        parameter services counts as up once discoverable. Stops early when a child of
        `supervisor` exits or `stop_event` is set. Returns (names not up: those not in the
        graph if any, else those not answering; name of a child that died meanwhile or
        None); an empty first list means all are up.
        """
        from lightstage_graph.qos import service_client
        from rcl_interfaces.srv import ListParameters

        deadline = time.monotonic() + timeout_s
        discovered_at: dict[str, float] = {}
        clients: dict[str, object] = {}  # name -> list_parameters client
        pending: dict[str, tuple[object, float]] = {}  # name -> (in-flight future, sent at)
        up: set[str] = set()
        renew_s = self.renew_s
        while True:
            now = time.monotonic()
            graph = self.node.get_node_names_and_namespaces()
            in_graph = {n for n, _ns in graph}
            # A renewal (below) drops the calls in flight, and a node busy in its set-up
            # answers a dropped call later into nothing (rmw blocks it for the profile's
            # max_blocking_time, then it logs "failed to send response"). So call only when
            # no renewal is due: every node is in the graph.
            may_call = all(n in in_graph for n in names)
            for n, ns in graph:
                if n not in names or n in up:
                    continue
                discovered_at.setdefault(n, now)
                if n not in clients:
                    services = {s for s, _t in self.node.get_service_names_and_types_by_node(n, ns)}
                    service = f'{ns.rstrip("/")}/{n}/list_parameters'
                    if service in services:
                        clients[n] = service_client(self.node, ListParameters, service)
                    elif now - discovered_at[n] > 2.0:  # no parameter services: discoverable is all
                        up.add(n)
                    continue
                if n in pending and pending[n][0].done():
                    up.add(n)
                elif may_call and clients[n].service_is_ready() and (
                        n not in pending or now - pending[n][1] > 1.0):
                    # (re)send: a request sent while the match is still settling can get lost
                    pending[n] = (clients[n].call_async(ListParameters.Request(depth=1)), now)
            missing = [n for n in names if n not in up]
            dead = supervisor.exited() if supervisor is not None else []
            stopped = stop_event is not None and stop_event.is_set()
            if not missing or dead or stopped or time.monotonic() >= deadline:
                # the nodes never seen in the graph if any (the others' spinning was not
                # asked yet; a renewal just before may hide a node it had seen)
                return ([n for n in missing if n not in discovered_at] or missing,
                        dead[0].name if dead else None)
            if any(n not in in_graph for n in missing) and now - self._opened_at > renew_s:
                renew_s *= 2
                self._close()
                self._open()
                clients.clear()
                pending.clear()
                continue
            self._executor.spin_once(timeout_sec=0.05)


def _params_section(params: Path | None, node: str) -> dict:
    """The ros__parameters a params file gives `node` (by its name or /name); {} if none."""
    if params is None:
        return {}
    import yaml
    try:
        doc = yaml.safe_load(params.read_text()) or {}
    except (OSError, yaml.YAMLError):
        return {}  # the node itself reports a params file it cannot read
    section = doc.get(node, doc.get('/' + node)) if isinstance(doc, dict) else None
    values = section.get('ros__parameters') if isinstance(section, dict) else None
    return values if isinstance(values, dict) else {}


def recorder_ros_args(bag: Path, params: Path | None) -> list[str]:
    """The recorder's `-p` overrides under `lightstage up`: its bag, node-qualified so that it
    wins over the params file's recorder section (a new bag per run), and the default
    recording limits where the params file does not set them."""
    args = ['-p', f'{RECORDER}:output_dir:={bag}']
    given = _params_section(params, RECORDER)
    for key, value in DEFAULT_RECORDING_LIMITS.items():
        if key not in given:
            args += ['-p', f'{RECORDER}:{key}:={value}']
    return args


def _new_bag_path(bag_dir: Path) -> Path:
    """A new, absolute bag path under bag_dir (created), named as `ros2 bag record` names bags."""
    from lightstage_recording.layout import default_bag_name
    bag_dir = bag_dir.resolve()
    bag_dir.mkdir(parents=True, exist_ok=True)
    bag = bag_dir / default_bag_name()
    n = 1
    while bag.exists():  # two runs within one second
        bag, n = bag_dir / f'{default_bag_name()}_{n}', n + 1
    return bag


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    err = sys.stderr

    try:
        registry = _registry_with_overrides(args.node)
    except ValueError as e:
        print(f'lightstage up: {e}', file=err)
        return EXIT_USAGE
    names = list(dict.fromkeys(args.nodes or DEFAULT_NODES))  # keep order, drop duplicates
    if not args.no_record and RECORDER not in names:
        names.insert(0, RECORDER)  # first: it records the others from their start
    unknown = [n for n in names if n not in registry]
    if unknown:
        print(f'lightstage up: unknown node(s) {", ".join(unknown)}; known: {", ".join(registry)} '
              f'(or add one with --node NAME=MODULE)', file=err)
        return EXIT_USAGE
    missing_modules = [(n, registry[n].module) for n in names if not _module_exists(registry[n].module)]
    if missing_modules:
        for n, m in missing_modules:
            print(f'lightstage up: node {n!r}: module {m} not found; it is not written yet or its '
                  f'package is not installed (pip install ./src/{m.split(".")[0]})', file=err)
        return EXIT_USAGE
    params = None
    if args.params is not None:
        params = Path(args.params).resolve()
        if not params.is_file():
            print(f'lightstage up: params file {args.params} does not exist; give a ROS parameters '
                  f'YAML (e.g. src/lightstage_bringup/config/lightstage.yaml)', file=err)
            return EXIT_USAGE
        try:  # a syntax error is named with its line here, not in every node's traceback
            read_params_file(params)
        except ValueError as e:
            print(f'lightstage up: {e}', file=err)
            return EXIT_USAGE
    if args.timeout_s <= 0:
        print('lightstage up: --timeout-s must be > 0', file=err)
        return EXIT_USAGE

    try:
        env = ros_environment(args.domain_id)
    except ValueError as e:
        print(f'lightstage up: {e}', file=err)
        return EXIT_USAGE
    domain_id = int(env.get('ROS_DOMAIN_ID', '0') or 0)
    if args.log_dir:
        Path(args.log_dir).mkdir(parents=True, exist_ok=True)
        env['ROS_LOG_DIR'] = str(Path(args.log_dir).resolve())

    extra_ros_args: dict[str, list[str]] = {}
    if RECORDER in names and not args.no_record:
        try:
            bag = _new_bag_path(Path(args.bag_dir))
        except OSError as e:
            print(f'lightstage up: cannot create the bag folder {args.bag_dir}: {e}; choose another '
                  f'with --bag-dir, or --no-record', file=err)
            return EXIT_USAGE
        extra_ros_args[RECORDER] = recorder_ros_args(bag, params)
        print(f'recording to {bag} (--no-record: off)', flush=True)

    stop = threading.Event()
    stop_reason: list[str] = []

    def on_signal(signum, _frame):
        stop_reason.append(signal.Signals(signum).name)
        stop.set()

    in_main_thread = threading.current_thread() is threading.main_thread()
    old_handlers = {}
    if in_main_thread:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old_handlers[sig] = signal.signal(sig, on_signal)

    rc = EXIT_OK
    supervisor = Supervisor(log_dir=args.log_dir, sigint_timeout_s=args.sigint_timeout_s,
                            sigterm_timeout_s=args.sigterm_timeout_s)
    try:
        t0 = time.monotonic()
        for n in names:
            supervisor.start(ProcessSpec(n, node_command(registry[n].module, n, params,
                                                         extra_ros_args.get(n)), env))
        with GraphWatcher(domain_id) as graph:  # after the starts: rclpy loads while they do
            missing, dead = graph.wait_for(names, args.timeout_s, supervisor, stop)
        if dead is not None:
            p = supervisor[dead]
            print(f'lightstage up: node {dead!r} died during start-up ({describe_exit(p.returncode)}); '
                  f'see its output above', file=err)
            rc = EXIT_NODE_FAILED
        elif stop.is_set():
            print(f'lightstage up: {stop_reason[0]} received during start-up; stopping', file=err)
        elif missing:
            print(f'lightstage up: node(s) {", ".join(missing)} not discoverable in the ROS graph '
                  f'(ROS_DOMAIN_ID={domain_id}) after {args.timeout_s:g} s, or not answering their '
                  f'parameter service; their processes run but have not created and spun a node '
                  f'named so (check their output above, or raise --timeout-s)', file=err)
            rc = EXIT_NOT_DISCOVERED
        else:
            up = ', '.join(f'{p.name} (pid {p.pid})' for p in supervisor.processes)
            print(f'graph up: {up} in {time.monotonic() - t0:.1f} s, ROS_DOMAIN_ID={domain_id}', flush=True)
            if not args.exit_after_up:
                dead_proc = supervisor.wait_for_exit(stop_event=stop)
                if dead_proc is not None:
                    print(f'lightstage up: node {dead_proc.name!r} died '
                          f'({describe_exit(dead_proc.returncode)}); stopping the others', file=err)
                    rc = EXIT_NODE_FAILED
                else:
                    print(f'lightstage up: {stop_reason[0]} received; stopping', file=err, flush=True)
    finally:
        reports = supervisor.shutdown()
        if in_main_thread:
            for sig, handler in old_handlers.items():
                signal.signal(sig, handler)
    for r in reports:
        if r.expected and not r.clean:
            print(f'lightstage up: {r.name} did not stop cleanly: {r}', file=err)
            rc = rc or EXIT_NODE_FAILED
    print('stopped: ' + '; '.join(str(r) for r in reports), file=err, flush=True)
    return rc


if __name__ == '__main__':
    sys.exit(main())
