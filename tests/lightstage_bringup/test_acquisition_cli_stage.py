"""`lightstage capture` / `lightstage calibrate` against a running driver and camera.

Their acquisition node killed (SIGKILL: no result, no goodbye) mid-goal, they end as failed
with the reason a few seconds later: the graph drops the node when its participant's lease
(5 s, the project's Fast DDS profile) ends, and the CLI gives up on the goal a grace period
after that (graph_client.goal_result). Their --camera-param values are typed and checked
as the camera node declares its parameters."""
import subprocess
import sys
import time

import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.acquisition import StageGraph
from helpers.ros import child_environment
from helpers.suite import fresh_domain_id, lightstage_command, write_params
from lightstage_physics.calibration_target import write_calibration_target

pytestmark = [pytest.mark.ros, pytest.mark.process]


@pytest.fixture(scope='module')
def stage(tmp_path_factory):
    """Driver and camera (a calibration target in front of it) running; the test's client."""
    root = tmp_path_factory.mktemp('stage')
    target = write_calibration_target(root / 'target', shape=(48, 64), dimmer=1.0)
    params = write_params(root / 'params.yaml', {
        'camera': {'capture_dir': str(target), 'sample': 0, 'dimmer': 1.0}})
    client = StageGraph(fresh_domain_id())
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            client.start(supervisor, ['driver', 'camera'], params)
            yield client
    finally:
        client.close()


def executing_goals(client, action: str):
    """A list that fills with the status arrays of `action` that show a goal executing."""
    from action_msgs.msg import GoalStatus, GoalStatusArray
    from rclpy.action.server import qos_profile_action_status_default
    seen = []
    client.node.create_subscription(
        GoalStatusArray, f'{action}/_action/status',
        lambda m: seen.append(m) if any(s.status == GoalStatus.STATUS_EXECUTING for s in m.status_list)
        else None, qos_profile_action_status_default)
    return seen


@pytest.mark.parametrize('verb', ['capture', 'calibrate'])
def test_a_cli_whose_acquisition_node_is_killed_mid_goal_fails_with_the_reason(stage, tmp_path, verb):
    from lightstage_graph.names import CALIBRATE_ACTION, CAPTURE_ACTION
    action = CAPTURE_ACTION if verb == 'capture' else CALIBRATE_ACTION
    running = executing_goals(stage, action)
    node = subprocess.Popen([sys.executable, '-m', 'lightstage_camera.acquisition_node'],
                            env=child_environment(stage.domain_id), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    # goals far longer than the test: many frames per image / per level
    args = ([str(tmp_path / 'models'), 'l/s/p', '--frames', '1000'] if verb == 'capture'
            else [str(tmp_path / 'noise.yaml'), '--frames', '1000', '--levels', '8'])
    cli = subprocess.Popen(lightstage_command(verb, *args, '--wait-s', '30', '--domain-id',
                                              str(stage.domain_id)),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stage.spin_until(lambda: running or cli.poll() is not None, 60, f'a {verb} goal executing')
        assert cli.poll() is None, cli.communicate()
        node.kill()
        killed_at = time.monotonic()
        out, err = cli.communicate(timeout=120)   # before: it never returned
        print(f'{verb}: the CLI ended {time.monotonic() - killed_at:.1f} s after the SIGKILL')
    finally:
        for proc in (cli, node):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert cli.returncode == 1, (out, err)
    assert f'the action server {action} went away while the goal ran' in err, err
    assert 'Traceback' not in err, err


def test_camera_params_are_checked_against_the_cameras_declared_type_and_range(stage):
    """`--camera-param dimmer=99` was refused as "wrong parameter type" without the range,
    and `dimmer=1` too, though a params file gives a float parameter a whole number."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    def calibrate(*params):   # a fresh process finds the camera in 1 s alone, not under load
        return subprocess.run(lightstage_command(
            'calibrate', *[a for p in params for a in ('--camera-param', p)], '--wait-s', '5',
            '--domain-id', str(stage.domain_id)), capture_output=True, text=True, timeout=120)

    p = calibrate('dimmer=99')
    assert p.returncode == 2, p.stderr
    assert p.stderr.startswith('lightstage calibrate: --camera-param dimmer: 99.0 is out of range: '
                               'give a number in 0.001 .. 10'), p.stderr
    p = calibrate('dimmer=bright')
    assert p.returncode == 2 and 'dimmer: must be a number in 0.001 .. 10, got \'bright\'' in p.stderr, p.stderr
    p = calibrate('dimmr=1')
    assert p.returncode == 2 and "camera node 'camera' has no parameter of that name" in p.stderr, p.stderr
    # a whole number for a float parameter is taken (then: no acquisition node in this graph)
    p = calibrate('dimmer=1', 'frame_id=007')
    assert p.returncode == 3 and 'the action /lightstage/calibrate_noise is not available' in p.stderr, p.stderr
    values = stage.call(GetParameters, '/camera/get_parameters',
                        GetParameters.Request(names=['dimmer', 'frame_id'])).values
    assert [parameter_value_to_python(v) for v in values] == [1.0, '007']
