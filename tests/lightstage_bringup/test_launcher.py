"""`lightstage up`: real child processes with tiny rclpy nodes, a graph check, shutdown paths.

The project's nodes are written by others; `--node NAME=MODULE` points the launcher at the
fake nodes in this directory (bringup_fake_node.py, bringup_no_graph_node.py) instead.
"""
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers.bringup import child_environment, fresh_domain_id, launcher_argv, pid_alive
from lightstage_bringup import launcher

from helpers.suite import REPO

pytestmark = [pytest.mark.ros, pytest.mark.process]

FAKE = 'bringup_fake_node'


def run_up(*args, timeout_s=40, domain_id=None):
    domain_id = fresh_domain_id() if domain_id is None else domain_id
    proc = subprocess.run(launcher_argv(*args, '--domain-id', str(domain_id)),
                          env=child_environment(domain_id), capture_output=True, text=True,
                          timeout=timeout_s)
    return proc


def test_up_starts_nodes_reports_graph_up_and_stops_cleanly_with_params_and_logs(tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text('alpha:\n  ros__parameters:\n    greeting: bonjour\n'
                      'beta:\n  ros__parameters:\n    greeting: hallo\n')
    logs = tmp_path / 'logs'
    p = run_up('alpha', 'beta', '--node', f'alpha={FAKE}', '--node', f'beta={FAKE}',
               '--params', str(params), '--log-dir', str(logs), '--exit-after-up')
    assert p.returncode == 0, p.stderr
    (up_line,) = [ln for ln in p.stdout.splitlines() if ln.startswith('graph up: ')]
    assert 'alpha (pid ' in up_line and 'beta (pid ' in up_line
    # each node got its own section of the params file and its registry name as node name
    assert '[alpha] greeting=bonjour name=alpha' in p.stdout
    assert '[beta] greeting=hallo name=beta' in p.stdout
    assert 'stopped: alpha' in p.stderr and 'after SIGINT' in p.stderr
    assert 'greeting=bonjour' in (logs / 'alpha.log').read_text()
    assert 'greeting=hallo' in (logs / 'beta.log').read_text()


def test_sigint_to_the_launcher_stops_every_node(tmp_path):
    domain_id = fresh_domain_id()
    proc = subprocess.Popen(launcher_argv('a', 'b', '--node', f'a={FAKE}', '--node', f'b={FAKE}',
                                          '--domain-id', str(domain_id)),
                            env=child_environment(domain_id), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        deadline = time.monotonic() + 30
        while not any(ln.startswith('graph up: ') for ln in lines):
            assert time.monotonic() < deadline and proc.poll() is None, lines
            lines.append(proc.stdout.readline())
        up = next(ln for ln in lines if ln.startswith('graph up: '))
        pids = [int(part.split(')')[0]) for part in up.split('(pid ')[1:]]
        assert len(pids) == 2 and all(pid_alive(pid) for pid in pids)
        time.sleep(0.5)  # running, not exiting by itself
        assert proc.poll() is None
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert 'SIGINT received; stopping' in err
    assert not any(pid_alive(pid) for pid in pids)


def test_a_node_dying_stops_the_rest_and_fails_naming_it(tmp_path):
    params = tmp_path / 'params.yaml'
    # it dies once the graph is up (about 1.5 s; a loaded 2-core machine took over 1 s at times)
    params.write_text('crasher:\n  ros__parameters:\n    die_after_s: 6.0\n    exit_code: 7\n')
    p = run_up('steady', 'crasher', '--node', f'steady={FAKE}', '--node', f'crasher={FAKE}',
               '--params', str(params))
    assert p.returncode == launcher.EXIT_NODE_FAILED
    assert 'graph up: ' in p.stdout
    assert "node 'crasher' died (exit code 7); stopping the others" in p.stderr
    assert 'steady (pid ' in p.stderr.split('stopped: ')[1]


def test_a_node_that_never_joins_the_graph_times_out_naming_it():
    t0 = time.monotonic()
    p = run_up('ok', 'ghost', '--node', f'ok={FAKE}', '--node', 'ghost=bringup_no_graph_node',
               '--timeout-s', '6')
    assert p.returncode == launcher.EXIT_NOT_DISCOVERED
    assert 'node(s) ghost not discoverable in the ROS graph' in p.stderr, p.stderr
    assert 'graph up' not in p.stdout
    assert '[ghost] starting, but never creating a ROS node' in p.stdout
    assert time.monotonic() - t0 < 20


def test_a_late_node_does_not_cost_a_busy_node_its_answer(tmp_path):
    """While a node is missing from the graph, the watcher renews its participant (so that
    the late node is found sooner), and a renewal drops its calls in flight. A node that is
    in the graph but busy in its set-up answered the dropped call later, into nothing: rmw
    blocked it for the profile's 2 s and it logged "failed to send response". The watcher
    now calls only once every node is in the graph."""
    params = tmp_path / 'params.yaml'
    params.write_text('busy:\n  ros__parameters:\n    spin_delay_s: 4.0\n')
    p = run_up('busy', 'late', '--node', f'busy={FAKE}', '--node', 'late=bringup_late_node',
               '--params', str(params), '--exit-after-up')
    assert p.returncode == 0, p.stderr
    assert 'graph up: ' in p.stdout
    assert 'failed to send response' not in p.stdout + p.stderr, p.stdout + p.stderr


def test_a_node_that_does_not_stop_on_sigint_is_escalated_and_reported(tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text('deaf:\n  ros__parameters:\n    ignore_sigint: true\n')
    p = run_up('deaf', '--node', f'deaf={FAKE}', '--params', str(params), '--exit-after-up',
               '--sigint-timeout-s', '1')
    # rclpy stops the node on SIGTERM, a normal way to stop a node: still a clean run
    assert 'deaf (pid ' in p.stderr and 'exit code 0 after SIGTERM' in p.stderr
    assert p.returncode == 0, p.stderr


def test_a_node_that_crashes_on_shutdown_fails_the_run(tmp_path):
    # a node whose SIGINT handling ends in an error exit: the run is not clean
    params = tmp_path / 'params.yaml'
    params.write_text('messy:\n  ros__parameters:\n    exit_code_on_stop: 5\n')
    p = run_up('messy', '--node', f'messy={FAKE}', '--params', str(params), '--exit-after-up')
    assert p.returncode == launcher.EXIT_NODE_FAILED
    assert 'messy did not stop cleanly: messy (pid ' in p.stderr and 'exit code 5 after SIGINT' in p.stderr


@pytest.mark.parametrize('args, message', [
    (['nosuchnode'], "unknown node(s) nosuchnode; known: driver, camera, classifier, trainer"),
    (['ghost', '--node', 'ghost=no_such_package.ghost_node'],
     "node 'ghost': module no_such_package.ghost_node not found"),
    (['x', '--node', 'x'], 'expected NAME=MODULE'),
    (['x', '--node', f'x={FAKE}', '--params', '/nonexistent/params.yaml'],
     'params file /nonexistent/params.yaml does not exist'),
    (['x', '--node', f'x={FAKE}', '--bag-dir', '/proc/no_bags_here'],
     'cannot create the bag folder /proc/no_bags_here'),
])
def test_bad_arguments_are_clear_errors_and_start_nothing(args, message, capsys):
    assert launcher.main(args) == launcher.EXIT_USAGE
    assert message in capsys.readouterr().err


def test_registry_points_at_the_project_node_modules():
    assert launcher.NODE_REGISTRY['driver'].module == 'lightstage_driver.driver_node'
    assert launcher.NODE_REGISTRY['camera'].module == 'lightstage_camera.camera_node'
    assert launcher.NODE_REGISTRY['classifier'].module == 'mux_classifier.classifier_node'
    assert launcher.NODE_REGISTRY['trainer'].module == 'mux_trainer.trainer_node'
    argv = launcher.node_command('pkg.mod', 'driver', '/p.yaml')
    assert argv[0] == sys.executable
    assert argv[argv.index('--ros-args'):] == ['--ros-args', '-r', '__node:=driver', '--params-file', '/p.yaml']


def test_up_with_the_project_nodes_and_config(tmp_path):
    """The default set (driver, camera, classifier) from the registry with the shipped params
    YAML: every node starts, spins and stops cleanly (unconfigured camera/classifier only log)."""
    config = REPO / 'src' / 'lightstage_bringup' / 'config' / 'lightstage.yaml'
    p = run_up('--params', str(config), '--exit-after-up', '--log-dir', str(tmp_path), timeout_s=60)
    assert p.returncode == 0, p.stdout + p.stderr
    (up_line,) = [ln for ln in p.stdout.splitlines() if ln.startswith('graph up: ')]
    for name in launcher.DEFAULT_NODES:
        assert f'{name} (pid ' in up_line
        assert (tmp_path / f'{name}.log').is_file()
    assert p.stderr.count('exit code 0 after SIGINT') == len(launcher.DEFAULT_NODES), p.stderr


# -- recording by default -------------------------------------------------------------
def _up_in(cwd: Path, *args, record: bool):
    domain_id = fresh_domain_id()
    p = subprocess.run(launcher_argv(*args, '--node', f'alpha={FAKE}', '--exit-after-up',
                                     '--domain-id', str(domain_id), record=record),
                       env=child_environment(domain_id), cwd=cwd, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stdout + p.stderr
    (up_line,) = [ln for ln in p.stdout.splitlines() if ln.startswith('graph up: ')]
    return p, up_line


def _bag_is_complete(bag: Path) -> bool:
    import yaml
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return info['storage_identifier'] == 'mcap' and all((bag / f).is_file() for f in info['relative_file_paths'])


def test_up_records_by_default_to_a_new_bag_under_out_bags(tmp_path):
    p, up_line = _up_in(tmp_path, 'alpha', record=True)
    assert 'recorder (pid ' in up_line
    (bag,) = (tmp_path / 'out' / 'bags').glob('rosbag2_*')  # the documented folder, cwd-relative
    assert f'recording to {bag} ' in p.stdout
    assert _bag_is_complete(bag)
    assert sorted(x.name for x in tmp_path.iterdir()) == ['out']  # nothing else written


def test_no_record_starts_no_recorder_and_writes_no_bag(tmp_path):
    p, up_line = _up_in(tmp_path, 'alpha', record=False)
    assert 'recorder' not in up_line and 'recording to' not in p.stdout
    assert list(tmp_path.iterdir()) == []


def test_bag_dir_wins_over_the_params_file_output_dir(tmp_path):
    """--bag-dir chooses the folder; a recorder output_dir in the params file (meant for `ros2
    run` / `lightstage record`) does not make every `lightstage up` write to one bag."""
    params = tmp_path / 'params.yaml'
    params.write_text(f'recorder:\n  ros__parameters:\n    output_dir: {tmp_path / "fixed"}\n')
    p, _ = _up_in(tmp_path, 'alpha', '--params', str(params), '--bag-dir', str(tmp_path / 'mine'),
                  record=True)
    (bag,) = (tmp_path / 'mine').glob('rosbag2_*')
    assert _bag_is_complete(bag) and not (tmp_path / 'fixed').exists()


def test_default_recording_is_bounded_unless_the_params_file_says_otherwise(tmp_path):
    """The recorder `lightstage up` starts by default splits its bag into 1 GiB files and keeps
    the newest 10; a params file's recorder section (the shipped one included) decides itself."""
    bag = tmp_path / 'bag'
    args = launcher.recorder_ros_args(bag, None)
    assert args == ['-p', f'recorder:output_dir:={bag}', '-p', f'recorder:max_bag_size_bytes:={1 << 30}',
                    '-p', 'recorder:max_bag_files:=10']
    params = tmp_path / 'params.yaml'
    params.write_text('recorder:\n  ros__parameters:\n    max_bag_files: 0\n')
    assert launcher.recorder_ros_args(bag, params) == [
        '-p', f'recorder:output_dir:={bag}', '-p', f'recorder:max_bag_size_bytes:={1 << 30}']
    shipped = REPO / 'src' / 'lightstage_bringup' / 'config' / 'lightstage.yaml'
    assert launcher.recorder_ros_args(bag, shipped) == ['-p', f'recorder:output_dir:={bag}']
