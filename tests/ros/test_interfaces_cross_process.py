"""The custom interfaces across processes: a message, a service call and an action with
feedback between node processes started through the supervisor (as `lightstage up` does).

The driver side runs twice: with a stand-in (ros_fake_driver_node.py) and with the real
lightstage_driver node on its Python firmware simulator. The trainer is a stand-in
(ros_fake_trainer_node.py) until mux_trainer.trainer_node exists; switching is a change
of TRAINER (and, for the real one, its parameters).
"""
import math

import numpy as np
import pytest
import yaml

from ros_helpers import RosClient, fresh_domain_id, running_nodes

pytestmark = pytest.mark.ros

# driver implementations: module whose main() runs it, its parameters
DRIVERS = {
    'stand-in': ('ros_fake_driver_node', {'frame_id': 'rig'}),
    # pwm_bits=8: a dimming rig, so IlluminationState carries the requested intensities
    'lightstage_driver': ('lightstage_driver.driver_node', {'frame_id': 'rig', 'port': 'sim://?pwm_bits=8'}),
}
TRAINER = ('ros_fake_trainer_node', {})
APPLY_PATTERNS = '/lightstage/apply_patterns'
ILLUMINATION = '/illumination'
TRAIN = '/trainer/train'


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
        client = RosClient(domain_id)
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
        np.testing.assert_array_equal(msg.intensities, p.intensities)  # float32 both ways
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


def test_train_action_streams_feedback_and_returns_a_result(graph):
    from lightstage_interfaces.action import Train
    from rclpy.action import ActionClient
    _sup, c = graph
    client = ActionClient(c.node, Train, TRAIN)
    c.spin_until(client.server_is_ready, 10, 'the Train action server')
    feedback = []
    goal = Train.Goal(capture_dir='/data/capture', output_path='/tmp/artifact.npz',
                      method='greedy', mode='per_colour', noise='sigma2', max_images=4,
                      repeats=3, seed=7)
    handle = c.result(client.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f.feedback)))
    assert handle.accepted
    result = c.result(handle.get_result_async(), 15, 'the Train result').result
    assert result.success
    assert result.artifact_path == '/tmp/artifact.npz'
    assert len(result.accuracy_by_images) == 4 and result.elapsed_s > 0
    # feedback arrives in order, one per column (reliable, on the same connection)
    assert [f.column for f in feedback] == [1, 2, 3, 4]
    assert feedback[-1].stage == 'column 4' and feedback[-1].candidates_total == 40
    np.testing.assert_allclose([f.best_accuracy for f in feedback], result.accuracy_by_images)
    # a goal the server refuses
    refused = c.result(client.send_goal_async(Train.Goal(max_images=0)))
    assert not refused.accepted
    client.destroy()
