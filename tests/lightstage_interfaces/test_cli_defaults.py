"""The interfaces are safe with the standard `ros2` CLI: `ros2 action send_goal` and `ros2
service call` fill every field left out with 0 / false / '', so a goal or pattern with its
fields at those defaults must run at the node's settings, not at 0 dB. Through the graph on
the simulated stage (driver, sim camera, acquisition node as processes), with the node's gains
set apart from 0 and from each other: a CaptureModel goal that gives only the names, and a
CalibrateNoise goal with every field at its default, run at the node's gain; a Pattern with
every field at its default is lit at the camera's gain (gain_db NaN on /illumination); 0 dB is
asked for with gain_db_set; NaN still means the node's gain."""
import math

import pytest
from lightstage_bringup.supervisor import Supervisor

from helpers.acquisition import StageGraph
from helpers.suite import fresh_domain_id, write_params
from lightstage_physics.calibration_target import write_calibration_target
from lightstage_physics.capture_format import load_capture

pytestmark = [pytest.mark.ros, pytest.mark.process]

CAPTURE_GAIN_DB, CALIBRATION_GAIN_DB = 12.0, 9.0
CAPTURE_ACTION, CALIBRATE_ACTION = '/lightstage/capture_model', '/lightstage/calibrate_noise'


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    root = tmp_path_factory.mktemp('defaults')
    target = write_calibration_target(root / 'target', shape=(24, 32), dimmer=1.0)
    params = write_params(root / 'params.yaml', {
        'camera': {'capture_dir': str(target), 'sample': '0', 'dimmer': 1.0, 'seed': 3},
        'acquisition': {'exposure_us': 2000, 'gain_db': CAPTURE_GAIN_DB, 'frames_averaged': 1,
                        'preview': False, 'calibration_exposure_us': 2000,
                        'calibration_gain_db': CALIBRATION_GAIN_DB, 'calibration_frames': 3,
                        'calibration_levels': 2},
    })
    client = StageGraph(fresh_domain_id())
    try:
        with Supervisor(sigint_timeout_s=5.0) as supervisor:
            client.start(supervisor, ['driver', 'camera', 'acquisition'], params)
            yield client
    finally:
        client.close()


def lit_gains(graph, since: int) -> set:
    """The gains [dB] /illumination reported for the triggers after the first `since`
    ('nan': the camera's own)."""
    return {'nan' if math.isnan(m.gain_db) else round(m.gain_db, 3) for m in graph.illumination[since:]}


def test_a_capture_goal_giving_only_the_names_runs_at_the_nodes_gain(graph, tmp_path):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import CaptureModel
    before = len(graph.illumination)
    goal = CaptureModel.Goal(output_dir=str(tmp_path), label='chart-flat', sample='s0', pose='p00')
    assert (goal.gain_db, goal.gain_db_set, goal.exposure_us) == (0.0, False, 0)   # as the CLI fills them
    status, result, _ = graph.action(CaptureModel, CAPTURE_ACTION, goal)
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert load_capture(tmp_path, cache=False).rig.gain_db == CAPTURE_GAIN_DB
    graph.spin_until(lambda: len(graph.illumination) >= before + 32, what='the 32 triggers')
    assert lit_gains(graph, before) == {CAPTURE_GAIN_DB}


@pytest.mark.parametrize('gain_db, gain_db_set, recorded', [
    (0.0, True, 0.0),                      # 0 dB, asked for
    (6.0, False, 6.0),                     # a gain given without the flag is the gain
    (math.nan, True, CAPTURE_GAIN_DB),     # NaN: the node's
])
def test_a_capture_goal_gets_the_gain_it_asks_for(graph, tmp_path, gain_db, gain_db_set, recorded):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import CaptureModel
    goal = CaptureModel.Goal(output_dir=str(tmp_path), label='chart-flat', sample='s0', pose='p00',
                             gain_db=gain_db, gain_db_set=gain_db_set)
    status, result, _ = graph.action(CaptureModel, CAPTURE_ACTION, goal)
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert load_capture(tmp_path, cache=False).rig.gain_db == recorded


def test_a_calibration_goal_with_every_field_at_its_default_runs_at_the_nodes_gain(graph):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import CalibrateNoise
    before = len(graph.illumination)
    status, result, _ = graph.action(CalibrateNoise, CALIBRATE_ACTION, CalibrateNoise.Goal())
    assert status == GoalStatus.STATUS_SUCCEEDED, result.message
    assert result.gain_db == CALIBRATION_GAIN_DB and result.output_path == ''
    assert lit_gains(graph, before) == {CALIBRATION_GAIN_DB}


def test_a_pattern_with_every_field_at_its_default_is_lit_at_the_cameras_gain(graph):
    from lightstage_interfaces.msg import Pattern
    from lightstage_interfaces.srv import ApplyPatterns
    before = len(graph.illumination)
    request = ApplyPatterns.Request(trigger=True, patterns=[
        Pattern(), Pattern(gain_db=0.0, gain_db_set=True), Pattern(gain_db=math.nan, gain_db_set=True)])
    answer = graph.call(ApplyPatterns, '/lightstage/apply_patterns', request)
    assert answer.success, answer.message
    graph.spin_until(lambda: len(graph.illumination) >= before + 3, what='the 3 triggers')
    gains = [m.gain_db for m in graph.illumination[before:before + 3]]
    assert math.isnan(gains[0]) and gains[1] == 0.0 and math.isnan(gains[2]), gains
