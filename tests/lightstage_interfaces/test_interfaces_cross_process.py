"""The custom interfaces across processes: a message, a service call and an action with
feedback between node processes started through the supervisor (as `lightstage up` does).

The driver side runs twice: with a stand-in (ros_fake_driver_node.py) and with the real
lightstage_driver node on its Python firmware simulator. The trainer is the real
mux_trainer node, training on a tiny synthetic capture folder.
"""
import math

import numpy as np
import pytest
import yaml

from helpers.ros import running_nodes
from helpers.suite import GraphClient, fresh_domain_id

pytestmark = [pytest.mark.ros, pytest.mark.process]

# driver implementations: module whose main() runs it, its parameters
DRIVERS = {
    'stand-in': ('ros_fake_driver_node', {'frame_id': 'rig'}),
    # pwm_bits=8: a graded rig, so IlluminationState carries the requested intensities rounded
    # to its 8-bit levels (what it applied)
    'lightstage_driver': ('lightstage_driver.driver_node', {'frame_id': 'rig', 'port': 'sim://?pwm_bits=8'}),
}
TRAINER = ('mux_trainer.trainer_node', {'n_jobs': 1})
APPLY_PATTERNS = '/lightstage/apply_patterns'
ILLUMINATION = '/illumination'
TRAIN = '/lightstage/train'


@pytest.fixture(scope='module', params=list(DRIVERS))
def graph(request, tmp_path_factory):
    """The driver and trainer node processes and a client node, shared by this module's tests."""
    driver_module, driver_params = DRIVERS[request.param]
    trainer_module, trainer_params = TRAINER
    params = tmp_path_factory.mktemp('params') / 'params.yaml'
    params.write_text(yaml.safe_dump({'driver': {'ros__parameters': driver_params},
                                      'trainer': {'ros__parameters': trainer_params}}))
    domain_id = fresh_domain_id()
    with running_nodes({'driver': driver_module, 'trainer': trainer_module}, domain_id,
                       params_file=str(params)) as sup:
        client = GraphClient(domain_id)
        try:
            yield sup, client
        finally:
            client.close()


def _patterns(n: int):
    from lightstage_interfaces.msg import Pattern
    rng = np.random.default_rng(3)
    patterns = []
    for i in range(n):
        p = Pattern()
        p.intensities = rng.random(32).astype(np.float32)
        p.exposure_us = 1000 * (i + 1)
        p.gain_db = float(i) / 2
        p.gain_db_set = True   # the first is 0 dB, asked for (without the flag: the camera's gain)
        patterns.append(p)
    return patterns


def test_apply_patterns_service_and_illumination_messages_cross_processes(graph):
    from lightstage_interfaces.msg import IlluminationState
    from lightstage_interfaces.srv import ApplyPatterns
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    _sup, c = graph
    received = []
    sub = c.node.create_subscription(IlluminationState, ILLUMINATION, received.append,
                                     QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    cli = c.node.create_client(ApplyPatterns, APPLY_PATTERNS)
    c.spin_until(lambda: cli.service_is_ready() and sub.get_publisher_count() > 0, 10,
                 'the driver service and the illumination publisher')
    # a first call without triggers: a round trip, so the topic match is complete both ways
    warm = c.call_until_answered(cli, ApplyPatterns.Request(patterns=_patterns(1), trigger=False))
    assert warm.success and warm.sequences.tolist() == [] and len(warm.trigger_stamps) == 0

    patterns = _patterns(3)
    resp = c.result(cli.call_async(ApplyPatterns.Request(patterns=patterns, trigger=True)))
    assert resp.success, resp.message
    assert resp.request_id > warm.request_id  # (+1, or more if a warm-up reply was lost)
    seqs = resp.sequences.tolist()
    assert len(seqs) == 3 and seqs == list(range(seqs[0], seqs[0] + 3))

    c.spin_until(lambda: len(received) >= 3, 10, 'three IlluminationState messages')
    assert len(received) == 3
    for i, (msg, p) in enumerate(zip(received, patterns)):
        assert msg.request_id == resp.request_id
        assert (msg.index_in_request, msg.count_in_request) == (i, 3)
        assert msg.sequence == seqs[i]
        assert msg.header.stamp == resp.trigger_stamps[i]
        assert msg.header.frame_id == 'rig'
        # float32 both ways; the real driver reports the drives rounded to 1/255 steps
        np.testing.assert_allclose(msg.intensities, p.intensities, rtol=0, atol=0.5 / 255 + 1e-6)
        assert msg.exposure_us == p.exposure_us and math.isclose(msg.gain_db, p.gain_db)
    c.node.destroy_subscription(sub)


def test_bad_request_is_refused_with_a_message_and_publishes_nothing(graph):
    from lightstage_interfaces.msg import IlluminationState
    from lightstage_interfaces.srv import ApplyPatterns
    _sup, c = graph
    received = []
    sub = c.node.create_subscription(IlluminationState, ILLUMINATION, received.append, 50)
    cli = c.node.create_client(ApplyPatterns, APPLY_PATTERNS)
    c.spin_until(lambda: cli.service_is_ready() and sub.get_publisher_count() > 0, 10, 'driver')
    c.call_until_answered(cli, ApplyPatterns.Request(patterns=_patterns(1), trigger=False))
    bad = _patterns(2)
    bad[1].intensities[5] = 1.5
    resp = c.result(cli.call_async(ApplyPatterns.Request(patterns=bad, trigger=True)))
    assert not resp.success
    assert 'pattern 1, LED 5' in resp.message
    assert len(resp.sequences) == 0
    c.spin_for(0.5)  # a message published by mistake would arrive within this
    assert received == []
    c.node.destroy_subscription(sub)


def test_train_action_streams_feedback_and_returns_a_result(graph, tiny_capture, tmp_path):
    from lightstage_interfaces.action import Train
    from mux_classifier.artifact import TrainedArtifact
    from rclpy.action import ActionClient
    _sup, c = graph
    client = ActionClient(c.node, Train, TRAIN)
    c.spin_until(client.server_is_ready, 10, 'the Train action server')
    feedback = []
    artifact = tmp_path / 'artifact.npz'
    goal = Train.Goal(capture_dir=str(tiny_capture), output_path=str(artifact),
                      method='greedy', mode='per_colour', noise='sigma2', max_images=2,
                      repeats=5, seed=7)
    handle = c.result(client.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f.feedback)))
    assert handle.accepted
    result = c.result(handle.get_result_async(), 60, 'the Train result').result
    assert result.success, result.message
    assert result.artifact_path == str(artifact)
    assert 1 <= len(result.accuracy_by_images) <= 2 and result.elapsed_s > 0
    assert TrainedArtifact.load(artifact).class_names == ['banana-fake', 'banana-real']
    # feedback arrives in order (reliable, on the same connection): loading, then per column
    assert feedback[0].stage == 'loading models'
    columns = [f.column for f in feedback[1:]]
    assert columns == sorted(columns) and columns[0] == 1
    done = [f for f in feedback if ': accuracy ' in f.stage]   # each column's end
    assert done and all(f.candidates_done == f.candidates_total == 254 for f in done)
    assert done[-1].best_accuracy == pytest.approx(max(result.accuracy_by_images))
    # within a column, the candidates scored so far (the rounds a cancel can stop between)
    rounds = [f.candidates_done for f in feedback if f.column == 1 and 'candidates scored' in f.stage]
    assert rounds == list(range(0, 254, 32)), rounds
    # a goal the server refuses, and one it accepts but cannot carry out
    refused = c.result(client.send_goal_async(Train.Goal(max_images=0)))
    assert not refused.accepted
    bad = c.result(client.send_goal_async(Train.Goal(capture_dir=str(tmp_path / 'missing'),
                                                     output_path=str(tmp_path / 'x.npz'))))
    assert bad.accepted
    bad_result = c.result(bad.get_result_async(), 30, 'the failed Train result').result
    assert not bad_result.success and 'no such capture folder' in bad_result.message
    # the node's features parameter picks the extractor; a bad name aborts a goal
    small = dict(capture_dir=str(tiny_capture), noise='sigma2', max_images=1, repeats=3)
    try:
        (ok,) = c.set_parameters('trainer', features='intensity_stats')
        assert ok.successful, ok.reason
        stats = tmp_path / 'stats.npz'
        done = c.result(client.send_goal_async(Train.Goal(output_path=str(stats), **small)))
        result = c.result(done.get_result_async(), 60, 'the intensity_stats Train result').result
        assert result.success, result.message
        assert TrainedArtifact.load(stats).features == 'intensity_stats'
        (ok,) = c.set_parameters('trainer', features='sift')
        assert ok.successful, ok.reason
        bad = c.result(client.send_goal_async(Train.Goal(output_path=str(tmp_path / 'y.npz'), **small)))
        bad_result = c.result(bad.get_result_async(), 30, 'the bad-features Train result').result
        assert not bad_result.success and "unknown feature extractor 'sift'" in bad_result.message
    finally:
        c.set_parameters('trainer', features='hog_grid')
    # a learned goal's feedback: each start begun and scored (a cancel stops between them)
    learned_feedback = []
    learned = c.result(client.send_goal_async(
        Train.Goal(capture_dir=str(tiny_capture), output_path=str(tmp_path / 'learned.npz'),
                   method='learned', noise='sigma2', max_images=4),
        feedback_callback=lambda f: learned_feedback.append(f.feedback)))
    result = c.result(learned.get_result_async(), 180, 'the learned Train result').result
    assert result.success, result.message
    stages = [f.stage for f in learned_feedback]
    assert stages[0] == 'loading models', stages
    assert stages[1].startswith('learned: start 1 of ') and stages[1].endswith('(random): scoring'), stages
    assert stages[2].startswith('learned: start 1 of ') and 'inner accuracy' in stages[2], stages
    assert learned_feedback[-1].best_accuracy == pytest.approx(max(result.accuracy_by_images))
    client.destroy()


def test_train_action_cancel_stops_at_a_column_boundary(graph, tiny_capture, tmp_path):
    from action_msgs.msg import GoalStatus
    from lightstage_interfaces.action import Train
    from rclpy.action import ActionClient
    _sup, c = graph
    client = ActionClient(c.node, Train, TRAIN)
    c.spin_until(client.server_is_ready, 10, 'the Train action server')
    feedback = []
    artifact = tmp_path / 'never.npz'
    goal = Train.Goal(capture_dir=str(tiny_capture), output_path=str(artifact), noise='sigma2',
                      max_images=8, repeats=5, seed=7)
    handle = c.result(client.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f.feedback)))
    assert handle.accepted
    c.spin_until(lambda: any(f.column >= 1 for f in feedback), 30, 'the first column to start')
    cancel = c.result(handle.cancel_goal_async(), 10, 'the cancel response')
    assert len(cancel.goals_canceling) == 1
    outcome = c.result(handle.get_result_async(), 60, 'the canceled Train result')
    assert outcome.status == GoalStatus.STATUS_CANCELED
    assert not outcome.result.success and 'canceled' in outcome.result.message
    assert not artifact.exists()
    client.destroy()
